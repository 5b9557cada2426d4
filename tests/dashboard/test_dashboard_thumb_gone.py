"""A thumbnail the dashboard already served (and cached) answers 410, as the full image does, once
its image was pruned or its file deleted; a browser revalidating it by its ETag gets the 410 too."""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import httpx
from service_test_support import AUTH, api_client, running_service, sim_config, to_execute

from cellctl.api.schemas import ErrorBody


@asynccontextmanager
async def _cycle_with_images(tmp_path: Path) -> AsyncIterator[tuple[Any, httpx.AsyncClient, int, list[Any]]]:
    """A served cell with one finished cycle: (service, client, cycle id, its first two image refs)."""
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as svc, api_client(svc) as c:
        await to_execute(c)
        rec = (await c.post("/cycle?wait=true", json={"recipe": "side-window", "part_id": "G-1"},
                            headers={**AUTH, "Idempotency-Key": "gone-1"})).json()  # fmt: skip
        yield svc, c, rec["id"], list((await svc.orchestrator.store.cycle(rec["id"])).images[:2])


async def _gone(svc: Any, pruned: Any, deleted: Any) -> None:
    """One image pruned by retention (file and reference), the other's file deleted behind the store's back."""
    assert await svc.orchestrator.store.mark_images_pruned([pruned.uri], reason="retention: test") == 1
    (svc.orchestrator.image_dir / deleted.uri).unlink()


async def test_a_served_thumbnail_is_gone_once_its_image_is(tmp_path: Path) -> None:
    async with _cycle_with_images(tmp_path) as (svc, c, cid, refs):
        for ref in refs:
            assert (await c.get(f"/dashboard/thumbs/{cid}/{ref.name}", params={"width": 64})).status_code == 200
        await _gone(svc, *refs)
        for ref in refs:
            full = await c.get(f"/cycles/{cid}/images/{ref.name}")
            assert full.status_code == 410, full.text
            r = await c.get(f"/dashboard/thumbs/{cid}/{ref.name}", params={"width": 64})
            assert r.status_code == 410, (ref.name, r.status_code)
            assert ErrorBody.model_validate(r.json()).detail == full.json()["detail"]


async def test_a_revalidated_thumbnail_is_unchanged_until_its_image_is_gone(tmp_path: Path) -> None:
    async with _cycle_with_images(tmp_path) as (svc, c, cid, refs):
        etags = {}
        for ref in refs:
            first = await c.get(f"/dashboard/thumbs/{cid}/{ref.name}", params={"width": 64})
            assert first.status_code == 200 and "no-cache" in first.headers["cache-control"]
            etags[ref.name] = first.headers["etag"]
            again = await c.get(f"/dashboard/thumbs/{cid}/{ref.name}", params={"width": 64}, headers={"If-None-Match": etags[ref.name]})
            assert again.status_code == 304 and again.content == b""  # unchanged: the browser keeps its copy
        await _gone(svc, *refs)
        for ref in refs:
            r = await c.get(f"/dashboard/thumbs/{cid}/{ref.name}", params={"width": 64}, headers={"If-None-Match": etags[ref.name]})
            assert r.status_code == 410, (ref.name, r.status_code)
