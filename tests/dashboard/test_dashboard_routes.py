"""The dashboard's routes over real HTTP: the page and its files come from the package and name no
outside host; the digest of recent cycles, the thumbnails and the periodic status events agree
with the cycle records and the configuration."""

from __future__ import annotations

import json
import re
import threading
import time
from collections.abc import Iterator
from datetime import UTC, datetime, timezone
from pathlib import Path

import cv2
import httpx
import numpy as np
import pytest
from dashboard_test_support import LiveCell, install_cycles, sim_config, to_aborted, to_execute

from cellctl.api.dashboard import (
    STALE_AFTER_S,
    STATIC_DIR,
    count_shift,
    deviation_digest,
    scale_png,
    shift_windows,
)
from cellctl.api.routes_cell import SSE_STATUS_PERIOD_S
from cellctl.cell.tags import CycleStep
from cellctl.store import CycleRecord, CycleRequest, CycleState
from cellctl.store.records import ImageRef, StepRecord

pytestmark = pytest.mark.timeout(120)

SVG_NAMESPACE = "http://www.w3.org/2000/svg"


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveCell]:
    config = sim_config(**{"process.tolerance": {"position_mm": 0.4, "orientation_deg": 0.8}})
    with LiveCell(tmp_path_factory.mktemp("dashboard-routes"), config) as live:
        yield live


@pytest.fixture(scope="module")
def client(cell: LiveCell) -> Iterator[httpx.Client]:
    with httpx.Client(base_url=cell.url, timeout=30.0) as c:
        yield c


@pytest.fixture(scope="module")
def two_cycles(client: httpx.Client) -> list[dict]:
    return install_cycles(client, "routes", [(f"P-R{i}", f"C-{i}") for i in range(2)])


def test_the_page_and_its_files_come_from_the_package(client: httpx.Client) -> None:
    r = client.get("/")
    assert r.status_code == 200
    assert r.headers["content-type"].startswith("text/html")
    html = r.text
    local = re.findall(r'(?:src|href)="([^"]+)"', html)
    assert "/ui/app.js" in local and "/ui/style.css" in local and "/ui/favicon.svg" in local
    assert "/ui/commissioning.js" in local
    # Every referenced file is served from the package with its media type.
    kinds = {"app.js": "javascript", "commissioning.js": "javascript", "style.css": "text/css", "favicon.svg": "image/svg+xml"}
    for name, kind in kinds.items():
        f = client.get(f"/ui/{name}")
        assert f.status_code == 200, name
        assert kind in f.headers["content-type"], (name, f.headers["content-type"])
        assert f.content == (STATIC_DIR / name).read_bytes()
    # Nothing names an outside host: no CDN, no web font, no absolute URL but the SVG namespace.
    for path in STATIC_DIR.iterdir():
        text = path.read_text(encoding="utf-8")
        urls = set(re.findall(r"(?:https?:)?//[A-Za-z0-9.-]+\.[A-Za-z]{2,}[^\s\"')]*", text)) - {SVG_NAMESPACE}
        assert urls == set(), (path.name, urls)
        assert "@import" not in text and "@font-face" not in text, path.name
    for href in local:
        assert href.startswith(("/", "#")), href
    assert client.get("/ui/../dashboard.py").status_code == 404


def test_the_dashboard_config_comes_from_the_cell_config(client: httpx.Client) -> None:
    cfg = client.get("/dashboard/config").json()
    assert cfg["tolerance"] == {"position_mm": 0.4, "orientation_deg": 0.8}
    assert cfg["simulation"] is True
    assert cfg["mode_change_states"] == ["STOPPED", "IDLE", "ABORTED"]
    assert cfg["status_period_s"] == SSE_STATUS_PERIOD_S
    assert cfg["stale_after_s"] == STALE_AFTER_S > SSE_STATUS_PERIOD_S


def test_the_cycle_digest_agrees_with_the_records(client: httpx.Client, two_cycles: list[dict]) -> None:
    digest = client.get("/dashboard/cycles", params={"limit": 5}).json()
    assert [d["id"] for d in digest] == [c["id"] for c in reversed(two_cycles)]
    for d in digest:
        rec = client.get(f"/cycles/{d['id']}").json()
        assert d["state"] == "done" and d["part_id"] == rec["part_id"] and d["car_id"] == rec["car_id"]
        assert d["true_error"] == pytest.approx(rec["true_error"])
        assert set(d["true_error"]) == {"dx_mm", "dy_mm", "dz_mm", "drx_deg", "dry_deg", "drz_deg"}
        res = rec["result"]
        assert [d["correction"][k] for k in ("dx_mm", "dy_mm", "dz_mm")] == pytest.approx(res["correction_mm"])
        assert [d["correction"][k] for k in ("drx_deg", "dry_deg", "drz_deg")] == pytest.approx(res["correction_deg"])
        assert d["cycle_time_s"] == pytest.approx(res["cycle_time_s"])
        last_comp = [s for s in rec["steps"] if s["step"] == "compensate"][-1]["figures"]
        assert [d["residual"]["dx_mm"], d["residual"]["dy_mm"]] == pytest.approx(last_comp["offset_mm"])
        assert d["residual"]["drz_deg"] == pytest.approx(last_comp["offset_deg"])
        assert d["residual"]["dz_mm"] is None
        assert d["image"]["url"] == rec["images"][-1]["url"]
    assert client.get("/dashboard/cycles", params={"limit": 0}).status_code == 422


def test_a_thumbnail_is_the_image_scaled_down(client: httpx.Client, two_cycles: list[dict]) -> None:
    cid = two_cycles[-1]["id"]
    name = two_cycles[-1]["images"][-1]["name"]
    full_png = client.get(f"/cycles/{cid}/images/{name}").content
    full = cv2.imdecode(np.frombuffer(full_png, np.uint8), cv2.IMREAD_UNCHANGED)
    r = client.get(f"/dashboard/thumbs/{cid}/{name}", params={"width": 240})
    assert r.status_code == 200 and r.headers["content-type"] == "image/png"
    thumb = cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_UNCHANGED)
    h, w = full.shape[:2]
    assert thumb.shape[:2] == (round(h * 240 / w), 240)
    expected = cv2.resize(full, (240, round(h * 240 / w)), interpolation=cv2.INTER_AREA)
    assert np.array_equal(thumb, expected)
    assert client.get(f"/dashboard/thumbs/{cid}/no-such-shot").status_code == 404
    assert client.get(f"/dashboard/thumbs/99999/{name}").status_code == 404
    assert client.get(f"/dashboard/thumbs/{cid}/{name}", params={"width": 8}).status_code == 422


def test_events_repeat_the_status_while_the_cell_is_quiet(client: httpx.Client) -> None:
    """The dashboard's stale mark relies on a status event at least every SSE_STATUS_PERIOD_S."""
    stamps: list[float] = []
    with client.stream("GET", "/events", timeout=10.0) as r:
        assert r.headers["content-type"].startswith("text/event-stream")
        for line in r.iter_lines():
            if line == "event: status":
                stamps.append(time.monotonic())
                if len(stamps) == 3:
                    break
    gaps = np.diff(stamps)
    assert gaps.max() < SSE_STATUS_PERIOD_S + 1.0, gaps


# ISA-88/PackML: the commands each of these states takes (no interlock holds one back in this cell).
PACKML_COMMANDS = {
    "ABORTED": ["clear"],
    "STOPPED": ["abort", "reset"],
    "IDLE": ["abort", "start", "stop"],
    "EXECUTE": ["abort", "complete", "hold", "stop", "suspend"],
}


def test_a_state_event_carries_the_commands_of_its_state(cell: LiveCell, client: httpx.Client) -> None:
    """The page patches the state from a state event; the commands must come with it, not stay the old state's
    (an Unhold greyed out in Held as "not allowed in HELD" until the next /status)."""
    to_execute(client)  # away from Aborted first, so that to_aborted below moves the cell (run alone, it starts there)
    events: list[dict] = []
    streaming = threading.Event()

    def listen() -> None:
        with httpx.Client(base_url=cell.url) as c, c.stream("GET", "/events", timeout=30.0) as r:
            kind = None
            for line in r.iter_lines():
                streaming.set()
                if line.startswith("event: "):
                    kind = line[len("event: ") :]
                elif line.startswith("data: ") and kind == "state":
                    events.append(json.loads(line[len("data: ") :]))
                    if events[-1]["state"] == "EXECUTE":
                        return

    t = threading.Thread(target=listen, daemon=True)
    t.start()
    assert streaming.wait(10.0)
    to_aborted(client)
    to_execute(client)
    t.join(20.0)
    assert not t.is_alive() and events, events
    seen = {e["state"]: e for e in events}
    for state in ("ABORTED", "EXECUTE"):  # the test waits in these, so the machine is still in them when told
        assert "allowed_commands" in seen[state], seen[state]
    for e in events:
        if "allowed_commands" in e and e["state"] in PACKML_COMMANDS:
            assert e["allowed_commands"] == PACKML_COMMANDS[e["state"]], e
            assert e["blocked_commands"] == {}, e


def _record(**changes: object) -> CycleRecord:
    t0 = datetime(2026, 1, 5, 8, 0, tzinfo=timezone.utc)
    base = dict(
        id=7, idempotency_scope="rest", idempotency_key="k", request=CycleRequest("side-window", "P-9", None),
        actor="operator", state=CycleState.FAILED, current_step=CycleStep.NONE, result=None, error="corner not found",
        true_error=None, created_at=t0, started_at=t0, finished_at=t0, install_started_at=None,
        interrupted_step=None, interrupted_at=None,
    )  # fmt: skip
    base.update(changes)
    return CycleRecord(**base)  # type: ignore[arg-type]


def test_the_digest_of_a_refused_cycle_has_no_figures_it_did_not_measure() -> None:
    d = deviation_digest(_record())
    assert d["correction"] is None and d["residual"] is None and d["true_error"] is None and d["image"] is None
    assert d["cycle_time_s"] is None and d["state"] == "failed" and d["error"] == "corner not found"
    t = datetime(2026, 1, 5, 8, 0, 1, tzinfo=timezone.utc)
    steps = (
        StepRecord(CycleStep.COMPENSATE, 1, t, t, 0.1, True, {"offset_mm": [1.5, -2.0], "offset_deg": 0.25}, None),
        StepRecord(CycleStep.COMPENSATE, 2, t, t, 0.1, False, {"corner_sigma_px": 9.0}, "corner not found"),
    )
    images = (ImageRef(CycleStep.COMPENSATE, "shot0", "cycle-7-shot0.png", t),)
    d = deviation_digest(_record(steps=steps, images=images, result={"error_code": 1302, "cycle_time_s": 4.5}))
    # The last step that measured an offset gives the residual; the failed shot measured none.
    assert d["residual"] == {"dx_mm": 1.5, "dy_mm": -2.0, "dz_mm": None, "drx_deg": None, "dry_deg": None, "drz_deg": 0.25}
    assert d["cycle_time_s"] == 4.5 and d["correction"] is None
    assert d["image"] == {"name": "shot0", "step": "compensate", "url": "/cycles/7/images/shot0", "thumb": "/dashboard/thumbs/7/shot0"}


def test_scale_png_refuses_what_is_not_an_image(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="not a readable PNG"):
        scale_png(b"not a png", 100)
    img = np.full((10, 20), 128, np.uint8)
    ok, png = cv2.imencode(".png", img)
    assert ok
    same = cv2.imdecode(np.frombuffer(scale_png(png.tobytes(), 64), np.uint8), cv2.IMREAD_UNCHANGED)
    assert same.shape == (10, 20)  # never enlarged


def test_shifts_begin_at_the_local_boundaries_and_count_good_and_not_ok_parts() -> None:
    utc = UTC
    now = datetime(2026, 1, 5, 4, 30, tzinfo=utc)  # 05:30 at UTC+1: the night shift since 22:00 yesterday
    (start, end, local), (prev_start, _, _) = shift_windows(now, ["06:00", "14:00", "22:00"], 60, 2)
    assert (start, end) == (datetime(2026, 1, 4, 21, 0, tzinfo=utc), datetime(2026, 1, 5, 5, 0, tzinfo=utc))
    assert local == datetime(2026, 1, 4, 22, 0) and prev_start == datetime(2026, 1, 4, 13, 0, tzinfo=utc)
    # Two shifts a day, given in any order.
    assert [w[2].hour for w in shift_windows(now, ["18:00", "06:00"], 0, 3)] == [18, 6, 18]
    t = datetime(2026, 1, 4, 22, 30, tzinfo=utc)
    records = [
        _record(id=1, state=CycleState.DONE, error=None, result={"part_ok": True, "cycle_time_s": 40.0}, finished_at=t),
        _record(id=2, state=CycleState.DONE, error=None, result={"part_ok": True, "cycle_time_s": 44.0}, finished_at=t),
        _record(id=3, state=CycleState.DONE, error=None, result={"part_ok": False, "cycle_time_s": 90.0}, finished_at=t),
        _record(id=4, state=CycleState.FAILED, finished_at=t),
        _record(id=5, state=CycleState.DONE, error=None, result={"cycle_time_s": 41.0}, finished_at=datetime(2026, 1, 4, 20, 0, tzinfo=utc)),
    ]
    assert count_shift(records, start, end) == (2, 2, 42.0)


def test_the_shift_route_checks_its_boundaries(client: httpx.Client) -> None:
    r = client.get("/dashboard/shifts", params={"starts": "06:00,18:00", "tz_offset_min": 120, "count": 4})
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["shift_starts"] == ["06:00", "18:00"] and len(body["shifts"]) == 4
    assert [s["current"] for s in body["shifts"]] == [True, False, False, False]
    assert client.get("/dashboard/config").json()["shift_starts"] == ["06:00", "14:00", "22:00"]
    for bad in ({"starts": "25:00"}, {"starts": "6:00"}, {"tz_offset_min": 900}, {"count": 0}):
        assert client.get("/dashboard/shifts", params=bad).status_code == 422, bad
