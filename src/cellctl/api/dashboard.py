"""The operator dashboard: the page at ``/``, its static files, and the feeds only it needs.

Everything the browser loads comes from ``cellctl/api/static`` in the package (no CDN, no web
fonts), so the screen works on a cell network without internet. The page reads the ordinary API
(/status, /alarms, /cycles, /calibration, /events) plus three small routes defined here:

- ``GET /dashboard/config``: tolerance bands, whether this is the simulated cell, the PackML
  states in which the unit mode may change, and the live-feed timing the stale mark is based on;
- ``GET /dashboard/cycles``: the recent cycles digested for the trend charts and the filmstrip
  (the six install deviations, the corrections, the verification residual, the cycle time and
  the last annotated image of each);
- ``GET /dashboard/thumbs/{cycle_id}/{name}``: a cycle image scaled down for the filmstrip;
- ``GET /dashboard/shifts``: good and not OK parts and the takt (median cycle time) of the
  current shift and the ones before it. Shifts begin at :data:`SHIFT_STARTS` (06:00, 14:00 and
  22:00) local time unless the request names others (``starts=06:00,18:00``); "local" is the
  page's time zone, which it sends by its IANA name (``tz=Europe/Berlin``: every shift's bounds
  follow that zone's daylight saving time), or, from a browser that names none, as one offset
  ``tz_offset_min`` (minutes east of UTC) for every shift.
"""

from __future__ import annotations

import asyncio
import statistics
from collections import OrderedDict
from dataclasses import asdict
from datetime import UTC, datetime, time, timedelta, timezone, tzinfo
from importlib import resources
from pathlib import Path
from typing import Any
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

import cv2
import numpy as np
from fastapi import APIRouter, FastAPI, Header, HTTPException, Query
from fastapi.responses import HTMLResponse, Response
from fastapi.staticfiles import StaticFiles

from cellctl.api.auth import TokenGuard
from cellctl.api.routes_cell import SSE_STATUS_PERIOD_S
from cellctl.api.routes_cycles import image_file
from cellctl.api.schemas import CycleId, ErrorBody
from cellctl.api.schemas_dashboard import (
    CycleDigest,
    DashboardConfig,
    ShiftCount,
    ShiftCounts,
    Tolerance,
)
from cellctl.cell.orchestrator import CellOrchestrator
from cellctl.cell.outcome import measured_of
from cellctl.domain import DEVIATION_KEYS, CycleStep
from cellctl.store import CycleRecord, CycleState, UnknownCycle

STATIC_DIR = Path(str(resources.files("cellctl.api") / "static"))
STALE_AFTER_S = 2.5 * SSE_STATUS_PERIOD_S
"""The page marks its data stale when nothing (event or periodic status) arrived for this long."""

THUMB_CACHE_SIZE = 256

SHIFT_STARTS = ("06:00", "14:00", "22:00")
"""Where a shift begins (local time) when the request names no other boundaries: three 8-hour shifts."""
_HHMM = r"([01][0-9]|2[0-3]):[0-5][0-9]"
SHIFT_STARTS_PATTERN = rf"^{_HHMM}(,{_HHMM}){{0,11}}$"
SHIFT_SCAN_PAGES = 10
"""At most this many pages of 1000 cycles are read to count the shifts."""


TZ_PATTERN = r"^[A-Za-z0-9_+\-/]{1,64}$"
"""What an IANA time zone name may look like (``Europe/Berlin``, ``Etc/GMT-3``); the tz database decides if it is one."""


def zone_named(name: str) -> ZoneInfo:
    """The time zone of an IANA name, from the tz database; 422 naming the field when it has none of that name."""
    try:
        return ZoneInfo(name)
    except (ZoneInfoNotFoundError, ValueError, OSError):
        raise HTTPException(422, detail=(
            f"query field 'tz': {name!r} is not a time zone this service's tz database knows; give an IANA name "
            "such as Europe/Berlin or America/New_York, or leave tz out and send tz_offset_min (minutes east of UTC)"
        )) from None  # fmt: skip


def local_to_utc(wall: datetime, zone: tzinfo) -> datetime:
    """When the naive local time ``wall`` begins in ``zone``, in UTC: of a time the clock shows twice (autumn)
    the first, of a time it skips (spring) the moment it jumps past it (the first minute after that exists)."""
    for minute in range(2 * 24 * 60):  # a gap is an hour, at most a day (Pacific/Apia skipped 2011-12-30)
        t = wall + timedelta(minutes=minute)
        utc = t.replace(tzinfo=zone).astimezone(UTC)
        if utc.astimezone(zone).replace(tzinfo=None) == t:
            return utc
    raise ValueError(f"{wall} never occurs in {zone}")


def shift_windows(
    now_utc: datetime, starts: list[str], zone: tzinfo | int, count: int
) -> list[tuple[datetime, datetime, datetime]]:
    """The current shift and the ``count - 1`` before it, newest first: (start UTC, end UTC, start local, naive).

    ``zone``: the plant's time zone (each bound in the offset it has then), or minutes east of UTC (one for all)."""
    tz = zone if isinstance(zone, tzinfo) else timezone(timedelta(minutes=zone))
    today = now_utc.astimezone(tz).date()
    minutes = sorted({int(h) * 60 + int(m) for h, m in (t.split(":") for t in starts)})
    days_back = count // len(minutes) + 2
    bounds = sorted({  # a set: two starts in one skipped hour begin at the same moment, the shift between is none
        local_to_utc(datetime.combine(today + timedelta(days=d), time()) + timedelta(minutes=m), tz)
        for d in range(-days_back, 2) for m in minutes
    })  # fmt: skip
    current = max(i for i, b in enumerate(bounds) if b <= now_utc)
    newest_first = range(current, current - count, -1)
    return [(bounds[i], bounds[i + 1], bounds[i].astimezone(tz).replace(tzinfo=None)) for i in newest_first]


def _utc(t: datetime) -> datetime:
    return t.replace(tzinfo=UTC) if t.tzinfo is None else t.astimezone(UTC)


def count_shift(records: list[CycleRecord], start: datetime, end: datetime) -> tuple[int, int, float | None]:
    """Good and not OK cycles that ended in [start, end), and the median cycle time of the good ones.

    A cycle a restart interrupted has no ``finished_at``: it ended when it was cut off (``interrupted_at``, its last
    step or image), in that shift, not when the next start found it (a ``GET /parts`` window lists it then)."""
    good, not_ok, times = 0, 0, []
    for r in records:
        ended = r.finished_at or r.interrupted_at
        if ended is None or not (start <= _utc(ended) < end):
            continue
        res = dict(r.result or {})
        if r.state is CycleState.DONE and res.get("part_ok", True) is not False:
            good += 1
            if isinstance(t := res.get("cycle_time_s"), int | float):
                times.append(float(t))
        elif r.state in (CycleState.DONE, CycleState.FAILED, CycleState.INTERRUPTED):
            not_ok += 1
    return good, not_ok, (statistics.median(times) if times else None)


def deviation_digest(record: CycleRecord) -> dict[str, Any]:
    """One cycle as the trend charts and the filmstrip need it.

    ``measured``: the six figures the inspection measured against the opening, None when not measured.
    ``true_error``: the twin's six install errors (simulation only), None elsewhere.
    ``correction``: the workpiece correction the cycle applied (mm, deg), None if it got no result.
    ``residual``: the last verification shot's in-plane offset (dx, dy mm; drz deg) from the
    compensate step, the cell's own measure of how far the glass still is from the template;
    the laser-aligned figures (dz, drx, dry) are not measured by that shot and stay None.
    """
    res = dict(record.result or {})
    true_error = None
    if record.true_error:
        te = dict(record.true_error)
        if all(isinstance(te.get(k), int | float) for k in DEVIATION_KEYS):
            true_error = {k: float(te[k]) for k in DEVIATION_KEYS}
    correction = None
    mm, deg = res.get("correction_mm"), res.get("correction_deg")
    if isinstance(mm, list | tuple) and isinstance(deg, list | tuple) and len(mm) == 3 and len(deg) == 3:
        correction = dict(zip(DEVIATION_KEYS, [float(v) for v in (*mm, *deg)], strict=True))
    residual = None
    for step in reversed(record.steps):
        fig = step.figures
        if step.step is CycleStep.COMPENSATE and "offset_mm" in fig and "offset_deg" in fig:
            dx, dy = (float(v) for v in fig["offset_mm"])
            residual = {"dx_mm": dx, "dy_mm": dy, "dz_mm": None, "drx_deg": None, "dry_deg": None, "drz_deg": float(fig["offset_deg"])}
            break
    image = None
    if record.images:
        last = record.images[-1]
        image = {
            "name": last.name,
            "step": last.step.name.lower(),
            "url": f"/cycles/{record.id}/images/{last.name}",
            "thumb": f"/dashboard/thumbs/{record.id}/{last.name}",
        }
    cycle_time = res.get("cycle_time_s")
    return {
        "id": record.id,
        "state": record.state.value,
        "part_id": record.request.part_id,
        "car_id": record.request.car_id,
        "recipe": record.request.recipe,
        "created_at": record.created_at.isoformat(),
        "finished_at": record.finished_at.isoformat() if record.finished_at else None,
        "current_step": record.current_step.name.lower(),
        "error": record.error,
        "cycle_time_s": float(cycle_time) if isinstance(cycle_time, int | float) else None,
        "measured": None if (m := measured_of(res)) is None else asdict(m),
        "part_ok": res.get("part_ok"),
        "true_error": true_error,
        "correction": correction,
        "residual": residual,
        "image": image,
    }


def scaled_png(img: np.ndarray, width: int) -> bytes:
    """An image as PNG, scaled to ``width`` pixels wide (aspect kept; never enlarged)."""
    h, w = img.shape[:2]
    if w > width:
        img = cv2.resize(img, (width, max(1, round(h * width / w))), interpolation=cv2.INTER_AREA)
    ok, out = cv2.imencode(".png", img)
    if not ok:
        raise ValueError("PNG encoding failed")
    return out.tobytes()


def scale_png(png: bytes, width: int) -> bytes:
    """The PNG scaled to ``width`` pixels wide (aspect kept; never enlarged)."""
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError("not a readable PNG image")
    return scaled_png(img, width)


def build_router(orch: CellOrchestrator, guard: TokenGuard) -> APIRouter:
    """The page itself is open (it holds no data); its feeds (``reads``) need read access."""
    router = APIRouter(tags=["dashboard"])
    reads = APIRouter(tags=["dashboard"], dependencies=guard.reads())
    thumbs: OrderedDict[tuple[int, str, int], bytes] = OrderedDict()

    @router.get("/", include_in_schema=False)
    async def index() -> HTMLResponse:
        html = (STATIC_DIR / "index.html").read_text(encoding="utf-8")
        return HTMLResponse(html, headers={"Cache-Control": "no-cache"})

    @reads.get("/dashboard/config", response_model=DashboardConfig)
    async def dashboard_config() -> DashboardConfig:
        cfg = orch.config
        return DashboardConfig(
            tolerance=Tolerance(position_mm=cfg.process.tolerance.position_mm, orientation_deg=cfg.process.tolerance.orientation_deg),
            simulation=cfg.mode == "sim",
            plc_enabled=cfg.plc.enabled,
            plc_heartbeat_alarm=cfg.plc.heartbeat_alarm,
            mode_change_states=[s.upper() for s in cfg.packml.mode_change_states],
            status_period_s=SSE_STATUS_PERIOD_S,
            stale_after_s=STALE_AFTER_S,
            calibration_max_age_days=float(cfg.calibration.max_age_days),
            shift_starts=list(SHIFT_STARTS),
        )

    @reads.get("/dashboard/shifts", response_model=ShiftCounts)
    async def dashboard_shifts(
        tz: str | None = Query(None, pattern=TZ_PATTERN, description=(
            "the page's time zone, an IANA name (Europe/Berlin): each shift's bounds in the offset the zone has then")),
        tz_offset_min: int = Query(0, ge=-840, le=840, description=(
            "without tz: the page's time zone as minutes east of UTC, one offset for every shift")),
        starts: str = Query(",".join(SHIFT_STARTS), pattern=SHIFT_STARTS_PATTERN, description="shift starts, HH:MM local, comma separated"),
        count: int = Query(3, ge=1, le=21, description="the current shift and this many minus one before it"),
    ) -> ShiftCounts:
        """Good and not OK parts per shift, newest shift first."""
        boundaries = starts.split(",")
        now = datetime.now(UTC)
        zone: tzinfo | int = tz_offset_min if tz is None else zone_named(tz)
        windows = shift_windows(now, boundaries, zone, count)
        oldest = windows[-1][0]
        records: list[CycleRecord] = []
        before: int | None = None
        for _ in range(SHIFT_SCAN_PAGES):
            page = await orch.store.cycles(limit=1000, before_id=before)
            records.extend(page)
            # A cycle finishes after it was created: once one was created a day before the oldest shift, stop.
            if len(page) < 1000 or _utc(page[-1].created_at) < oldest - timedelta(days=1):
                break
            before = page[-1].id
        shifts = []
        for i, (start, end, local) in enumerate(windows):
            good, not_ok, takt = count_shift(records, start, end)
            shifts.append(ShiftCount(
                start_utc=start.isoformat(), end_utc=end.isoformat(), start_local=local.strftime("%Y-%m-%d %H:%M"),
                current=i == 0, good=good, not_ok=not_ok, median_cycle_time_s=takt,
            ))  # fmt: skip
        now_offset = now.astimezone(zone).utcoffset() if isinstance(zone, tzinfo) else None
        offset = tz_offset_min if now_offset is None else now_offset // timedelta(minutes=1)
        return ShiftCounts(shift_starts=sorted(set(boundaries)), tz=tz, tz_offset_min=offset, shifts=shifts)

    @reads.get("/dashboard/cycles", response_model=list[CycleDigest])
    async def dashboard_cycles(limit: int = Query(40, ge=1, le=200)) -> list[CycleDigest]:
        """The newest cycles first, each with its deviations, cycle time and last image."""
        out = []
        for brief in await orch.store.cycles(limit=limit):
            try:
                record = await orch.store.cycle(brief.id)
            except UnknownCycle:
                continue
            out.append(CycleDigest.model_validate(deviation_digest(record)))
        return out

    @reads.get(
        "/dashboard/thumbs/{cycle_id}/{name}", response_class=Response,
        responses={
            200: {"content": {"image/png": {}}, "description": "the image scaled down (PNG)"},
            410: {"model": ErrorBody, "description": "the image was pruned or its file is no longer on disk"},
        },
    )  # fmt: skip
    async def thumb(
        cycle_id: CycleId, name: str, width: int = Query(256, ge=32, le=1024), if_none_match: str | None = Header(None),
    ) -> Response:
        """The image scaled down. Checked against the store on every request (the browser revalidates
        by ETag), so once the image is pruned or its file deleted the thumbnail is a 410 too."""
        try:
            path = await image_file(orch, cycle_id, name)
        except HTTPException:
            for key in [k for k in thumbs if k[:2] == (cycle_id, name)]:
                del thumbs[key]
            raise
        st = path.stat()
        headers = {"Cache-Control": "private, no-cache", "ETag": f'"{cycle_id}-{width}-{st.st_mtime_ns}-{st.st_size}"'}
        if if_none_match == headers["ETag"]:
            return Response(status_code=304, headers=headers)
        key = (cycle_id, name, width)
        png = thumbs.get(key)
        if png is None:
            png = await asyncio.to_thread(lambda: scale_png(path.read_bytes(), width))
            thumbs[key] = png
            while len(thumbs) > THUMB_CACHE_SIZE:
                thumbs.popitem(last=False)
        thumbs.move_to_end(key)
        return Response(png, media_type="image/png", headers=headers)

    router.include_router(reads)
    return router


def install(app: FastAPI, orch: CellOrchestrator, guard: TokenGuard) -> None:
    """Serve the dashboard page at ``/``, its files under ``/ui/``, and its feeds."""
    app.include_router(build_router(orch, guard))
    app.mount("/ui", StaticFiles(directory=str(STATIC_DIR)), name="dashboard-ui")
