"""Every recorded part id can be looked up: ids with "/" (part numbers such as 8K0/845/201), "." and "..",
a literal "%2F" and non-ASCII text. The simulated cell is served on a loopback port; its installs are
looked up over REST (httpx), with the real ``cellctl parts show`` in a subprocess, and checked against
sqlite3 reading the store's database (the independent reader: which cycle recorded which part id).
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import sqlite3
import sys
from pathlib import Path
from urllib.parse import quote

import httpx
from service_test_support import AUTH, ROOT, TOKEN, running_service, served, sim_config, to_execute


IDS = ("8K0/845/201", ".", "..", "a%2Fb", "Ä/ü 1")
DOTS = (".", "..")


async def parts_show(url: str, part_id: str) -> tuple[int, str, str]:
    """``cellctl parts show PART_ID`` in a subprocess, the operator's token in its environment."""
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "cellctl.cli", "--config", str(ROOT / "config" / "sim.toml"), "parts", "show", "--url", url,
        part_id, stdin=asyncio.subprocess.DEVNULL, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
        env={**os.environ, "CELLCTL_TOKEN": TOKEN},
    )  # fmt: skip
    out, err = await asyncio.wait_for(proc.communicate(), 60)
    return int(proc.returncode or 0), out.decode(), err.decode()


def recorded(db: Path) -> dict[str, list[int]]:
    """Part id -> its cycles' ids, as sqlite3 reads them from the store."""
    with contextlib.closing(sqlite3.connect(f"file:{db}?mode=ro", uri=True)) as con:
        rows = con.execute("select part_id, id from cycles order by id").fetchall()
    ids: dict[str, list[int]] = {}
    for part_id, cycle_id in rows:
        ids.setdefault(part_id, []).append(cycle_id)
    return ids


def history_of(r: httpx.Response) -> tuple[object, list[int]] | str:
    """The part id and cycle ids of a part history answer, else what came instead."""
    if r.status_code != 200 or not r.headers["content-type"].startswith("application/json"):
        return f"{r.status_code} {r.text[:80]!r}"
    body = r.json()
    return (body.get("part_id"), [i["cycle_id"] for i in body.get("installs", [])])


async def test_every_recorded_part_id_is_found_by_rest_and_the_cli(tmp_path: Path) -> None:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as service, served(service) as url:
        async with httpx.AsyncClient(base_url=url, headers=AUTH, timeout=120) as client:
            await to_execute(client)
            for n, part_id in enumerate(IDS):
                body = {"recipe": "side-window", "part_id": part_id}
                r = await client.post("/cycle", params={"wait": "true", "timeout_s": 100}, json=body,
                                      headers={"Idempotency-Key": f"any-characters-{n}"})  # fmt: skip
                assert r.status_code == 200 and r.json()["state"] == "done", r.text
            truth = recorded(tmp_path / "var" / "cellctl.db")
            assert sorted(truth) == sorted(IDS) and all(len(c) == 1 for c in truth.values()), truth

            problems: list[str] = []  # every form's failures, each id's (so one run shows them all)
            for part_id in IDS:
                # the path form: percent-encoded ("/" as %2F), and "/" as is; "." and ".." fold in a URL path, but
                # percent-encoded httpx sends them as they are
                paths = ["%2E" * len(part_id)] if part_id in DOTS else [quote(part_id, safe="")]
                paths += [quote(part_id, safe="/")] if "/" in part_id else []
                expected = (part_id, truth[part_id])
                for path in paths:
                    if (got := history_of(await client.get(f"/parts/{path}"))) != expected:
                        problems.append(f"GET /parts/{path} -> {got}")
                code, stdout, stderr = await parts_show(url, part_id)
                shown = stdout.startswith(f"glass {part_id}: 1 install\n") and f"cycle {truth[part_id][0]}: done OK" in stdout
                if code != 0 or not shown:
                    problems.append(f"cellctl parts show {part_id!r} -> exit {code}: {(stdout + stderr).strip()[-160:]!r}")
                if (got := history_of(await client.get("/part-history", params={"part_id": part_id}))) != expected:
                    problems.append(f"GET /part-history?part_id={part_id} -> {got}")  # the form for every id
            assert not problems, "\n".join(problems)

            # a glass never recorded: its id named, no bare 404, no traceback
            for part_id in ("8K0/845/999", ".x", "b%2Fa"):
                said = f"no glass with part id {part_id!r} is recorded"
                for r in (await client.get("/part-history", params={"part_id": part_id}),
                          await client.get(f"/parts/{quote(part_id, safe='')}")):  # fmt: skip
                    assert r.status_code == 404 and r.json()["detail"].startswith(said), r.text
                code, stdout, stderr = await parts_show(url, part_id)
                assert code == 1 and stdout == "" and said in stderr and "Traceback" not in stderr, stderr


async def test_the_list_is_still_the_list_and_both_forms_are_documented(tmp_path: Path) -> None:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as service, served(service) as url:
        async with httpx.AsyncClient(base_url=url, headers=AUTH) as client:
            assert (await client.get("/parts")).json() == {"installs": [], "next": None, "until": None}
            r = await client.get("/parts/", follow_redirects=True)  # not a glass with an empty id: the list, as before
            assert r.status_code == 200 and r.json() == {"installs": [], "next": None, "until": None}, r.text
            schema = (await client.get("/openapi.json")).json()
    history = {"$ref": "#/components/schemas/PartHistory"}
    for path, where in (("/parts/{part_id}", "path"), ("/part-history", "query")):
        op = schema["paths"][path]["get"]
        assert op["responses"]["200"]["content"]["application/json"]["schema"] == history, (path, op["responses"])
        assert "ErrorBody" in str(op["responses"]["404"]), (path, op["responses"])
        assert [(p["name"], p["in"], p["required"]) for p in op["parameters"]] == [("part_id", where, True)], op["parameters"]
    assert not [p for p in schema["paths"] if ":" in p], list(schema["paths"])
    assert schema["paths"]["/parts"]["get"]["responses"]["200"]["content"]["application/json"]["schema"] == {
        "$ref": "#/components/schemas/PartsPage"
    }
