"""Part traceability: ``GET /parts`` (installs by car body, glass and time window), one glass's history.

A glass's history is ``GET /parts/{part_id}`` (the id percent-encoded; it may hold "/", which
Starlette decodes before routing, so the route takes the rest of the path) and
``GET /part-history?part_id=``, the form that carries every id: URL paths fold "." and "..".

Each install is the document of :class:`cellctl.api.schemas_parts.PartInstall`. Its images are
checked against the SHA-256 recorded when they were written, on every request (the files are read
and hashed off the event loop): the status says whether the file is still what the cell wrote.
The time window and the paging are those of :mod:`cellctl.store.parts`.
"""

from __future__ import annotations

import asyncio
import hashlib
from collections.abc import Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Query, status
from fastapi import Path as PathParam
from pydantic import AfterValidator, BeforeValidator
from starlette.convertors import PathConvertor, register_url_convertor

from cellctl.api.auth import TokenGuard
from cellctl.api.routes_cell import alarm_view
from cellctl.api.routes_cycles import cycle_view
from cellctl.api.schemas import SQLITE_INT_MAX, ErrorBody
from cellctl.api.schemas_parts import ImageStatus, PartAction, PartHistory, PartImage, PartInstall, PartsPage
from cellctl.cell.orchestrator import CellOrchestrator
from cellctl.cell.outcome import calibration_version_of, recipe_settings_of, result_message
from cellctl.store.parts import MAX_PAGE
from cellctl.store.parts import PartInstall as StoredInstall
from cellctl.store.records import MAX_TEXT_LEN, ImageRef

PAGE_MAX = 200
"""The most installs one ``GET /parts`` answers (each install's images are read and hashed)."""

TIME_FORMAT = "ISO 8601 with a timezone, e.g. 2025-03-01T06:00:00+01:00 or 2025-03-01T05:00:00Z"

HISTORY_QUERY = "/part-history"
"""One glass's history by a query parameter: it carries any part id, "/", "." and ".." included."""


class PartIdConvertor(PathConvertor):
    """A part id as the rest of a URL path: any characters, "/" included, at least one (``/parts/`` stays the list)."""

    regex = ".+"


register_url_convertor("part_id", PartIdConvertor())


def aware_utc(t: datetime) -> datetime:
    """``t`` in UTC; a time without a timezone (ambiguous) or out of range is refused, saying what to send."""
    if t.tzinfo is None or t.utcoffset() is None:
        raise ValueError(f"{t.isoformat()} has no timezone; give {TIME_FORMAT}")
    try:
        return t.astimezone(timezone.utc)
    except OverflowError:
        raise ValueError(f"{t.isoformat()} is out of range once converted to UTC") from None


def not_a_number(v: object) -> object:
    """Refuse a number: pydantic would read it as Unix seconds (milliseconds above 2e10), not the ISO 8601 promised."""
    if isinstance(v, bool) or not isinstance(v, str | int | float):
        return v
    try:
        float(v)
    except ValueError:
        return v
    raise ValueError(f"{v!r} is a number, not a time; give {TIME_FORMAT}")


Moment = Annotated[datetime, BeforeValidator(not_a_number), AfterValidator(aware_utc)]


def file_sha256(path: Path) -> str:
    """The SHA-256 (hex) of a file's bytes."""
    with path.open("rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def image_status(image_dir: Path, ref: ImageRef) -> ImageStatus:
    """What an image's file is now, against the digest recorded when it was written."""
    if ref.pruned:
        return "pruned"
    path = image_dir / ref.uri
    try:
        if not path.is_file():
            return "missing"
        if ref.sha256 is None:
            return "unrecorded"
        if ref.size_bytes is not None and path.stat().st_size != ref.size_bytes:
            return "altered"
        return "ok" if file_sha256(path) == ref.sha256 else "altered"
    except OSError:  # unreadable (permissions, I/O error): it cannot be shown to be the image
        return "missing"


def part_install(image_dir: Path, install: StoredInstall) -> PartInstall:
    """The traceability document of one install (reads and hashes its image files: call it off the event loop)."""
    record = install.record
    view = cycle_view(record)
    outcome = result_message(record) or {}
    corrected = "correction_mm" in (record.result or {})  # a cycle that failed before compensating applied none

    def iso(t: datetime | None) -> str | None:
        return None if t is None else t.isoformat()

    images = [
        PartImage(
            name=ref.name, step=ref.step.name.lower(), uri=ref.uri, url=f"/cycles/{record.id}/images/{ref.name}",
            created_at=ref.created_at.isoformat(), sha256=ref.sha256, size_bytes=ref.size_bytes,
            status=image_status(image_dir, ref), pruned_at=iso(ref.pruned_at), pruned_reason=ref.pruned_reason,
        )
        for ref in record.images
    ]  # fmt: skip
    actions = [
        PartAction(
            seq=a.seq, at=a.at.isoformat(), actor=a.actor, source=a.source, action=a.action, params=dict(a.params),
            state_before=a.state_before, state_after=a.state_after, result=a.result, hash=a.hash,
        )
        for a in install.actions.audit
    ]  # fmt: skip
    return PartInstall(
        cycle_id=record.id, recipe=view.recipe, part_id=view.part_id, car_id=view.car_id, source=view.source,
        actor=view.actor, state=view.state, created_at=view.created_at, started_at=view.started_at,
        finished_at=view.finished_at, install_started_at=view.install_started_at, interrupted_at=iso(record.interrupted_at),
        ended_at=iso(install.ended_at), interrupted_step=view.interrupted_step, calibration_version=calibration_version_of(record),
        recipe_settings=recipe_settings_of(record),
        ok=outcome.get("ok"), error_code=outcome.get("error_code"), reason=outcome.get("reason"),
        measured_deviation=view.measured_deviation, correction_mm=outcome.get("correction_mm") if corrected else None,
        correction_deg=outcome.get("correction_deg") if corrected else None, cycle_time_s=outcome.get("cycle_time_s"),
        steps=view.steps,
        images=images, actions=actions, alarms=[alarm_view(a) for a in install.actions.alarms],
    )  # fmt: skip


async def part_installs(image_dir: Path, installs: Sequence[StoredInstall]) -> list[PartInstall]:
    """The documents of ``installs``, their image files read and hashed on a worker thread."""
    return await asyncio.to_thread(lambda: [part_install(image_dir, i) for i in installs])


def build_router(orch: CellOrchestrator, guard: TokenGuard) -> APIRouter:
    """Every route is a read (read access, like ``/cycles``)."""
    reads = APIRouter(tags=["parts"], dependencies=guard.reads())

    @reads.get("/parts", response_model=PartsPage)
    async def list_parts(
        car_id: Annotated[str | None, Query(min_length=1, max_length=MAX_TEXT_LEN, description="the car body")] = None,
        part_id: Annotated[str | None, Query(min_length=1, max_length=MAX_TEXT_LEN, description="the glass")] = None,
        since: Annotated[Moment | None, Query(description=f"installs that ended (`ended_at`) at or after this time ({TIME_FORMAT})")] = None,
        until: Annotated[Moment | None, Query(description="installs that ended before this time (same format; see the answer's `until`)")] = None,
        limit: int = Query(50, ge=1, le=PAGE_MAX, description="installs per page"),
        after: int | None = Query(None, ge=0, le=SQLITE_INT_MAX, description="the previous page's `next`"),
    ) -> PartsPage:
        """Installs of a car body (``car_id``), of a glass (``part_id``), or that ended in a time window; filters combine.

        A window lists ended cycles only (``since`` inclusive, ``until`` exclusive); without one, queued
        and running cycles are listed too. Pages run by ascending cycle id.
        """
        if since is not None and until is not None and until <= since:
            raise HTTPException(422, detail=f"query field 'until': {until.isoformat()} must be later than since ({since.isoformat()})")
        page = await orch.store.part_installs(car_id=car_id, part_id=part_id, since=since, until=until, after_id=after, limit=limit)
        return PartsPage(installs=await part_installs(orch.image_dir, page.installs), next=page.next_after,
                         until=None if page.until is None else page.until.isoformat())

    not_found: dict[int | str, dict[str, Any]] = {404: {"model": ErrorBody, "description": "no install of this glass is recorded"}}

    async def history(part_id: str) -> PartHistory:
        """Every install of ``part_id``, oldest first; 404 naming the id when none is recorded."""
        installs: list[StoredInstall] = []
        after: int | None = None
        while True:
            page = await orch.store.part_installs(part_id=part_id, after_id=after, limit=MAX_PAGE)
            installs.extend(page.installs)
            if page.next_after is None:
                break
            after = page.next_after
        if not installs:
            raise HTTPException(
                status.HTTP_404_NOT_FOUND,
                detail=f"no glass with part id {part_id!r} is recorded (retention may have pruned it; GET /parts lists what is kept)",
            )
        return PartHistory(part_id=part_id, installs=await part_installs(orch.image_dir, installs))

    @reads.get(HISTORY_QUERY, response_model=PartHistory, responses=not_found)
    async def get_part_history(
        part_id: Annotated[str, Query(min_length=1, max_length=MAX_TEXT_LEN, description="the glass: any part id")],
    ) -> PartHistory:
        """Every install of one glass, oldest first: the form for every part id ("/", "." and ".." included)."""
        return await history(part_id)

    @reads.get("/parts/{part_id:part_id}", response_model=PartHistory, responses=not_found)
    async def get_part(
        part_id: Annotated[str, PathParam(min_length=1, max_length=MAX_TEXT_LEN, description=(
            "the glass, percent-encoded (a '/' in it may be sent as is or as %2F); a URL path cannot carry the ids "
            f"'.' and '..' (clients fold them): {HISTORY_QUERY}?part_id= takes every id"))],
    ) -> PartHistory:  # fmt: skip
        """Every install of one glass, oldest first (the same as ``GET /part-history?part_id=``)."""
        return await history(part_id)

    return reads
