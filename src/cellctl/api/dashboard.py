"""The operator dashboard: the page at ``/``, its static files, and the feeds only it needs.

Everything the browser loads comes from ``cellctl/api/static`` in the package (no CDN, no web
fonts), so the screen works on a cell network without internet. The page reads the ordinary API
(/status, /alarms, /cycles, /calibration, /events) plus three small routes defined here:

- ``GET /dashboard/config``: tolerance bands, whether this is the simulated cell, the PackML
  states in which the unit mode may change, and the live-feed timing the stale mark is based on;
- ``GET /dashboard/cycles``: the recent cycles digested for the trend charts and the filmstrip
  (the six install deviations, the corrections, the verification residual, the cycle time and
  the last annotated image of each);
- ``GET /dashboard/thumbs/{cycle_id}/{name}``: a cycle image scaled down for the filmstrip.
"""

from __future__ import annotations

import asyncio
from collections import OrderedDict
from dataclasses import asdict
from importlib import resources
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from fastapi import APIRouter, FastAPI, Query
from fastapi.responses import HTMLResponse, Response
from fastapi.staticfiles import StaticFiles

from cellctl.api.auth import TokenGuard
from cellctl.api.routes_cell import SSE_STATUS_PERIOD_S
from cellctl.api.routes_cycles import image_file
from cellctl.api.schemas import CycleId
from cellctl.api.schemas_dashboard import CycleDigest, DashboardConfig, Tolerance
from cellctl.cell.orchestrator import CellOrchestrator
from cellctl.cell.outcome import measured_of
from cellctl.cell.tags import CycleStep
from cellctl.domain import DEVIATION_KEYS
from cellctl.store import CycleRecord, UnknownCycle

STATIC_DIR = Path(str(resources.files("cellctl.api") / "static"))
STALE_AFTER_S = 2.5 * SSE_STATUS_PERIOD_S
"""The page marks its data stale when nothing (event or periodic status) arrived for this long."""

THUMB_CACHE_SIZE = 256


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
        )

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
        responses={200: {"content": {"image/png": {}}, "description": "the image scaled down (PNG)"}},
    )  # fmt: skip
    async def thumb(cycle_id: CycleId, name: str, width: int = Query(256, ge=32, le=1024)) -> Response:
        key = (cycle_id, name, width)
        png = thumbs.get(key)
        if png is None:
            path = await image_file(orch, cycle_id, name)
            png = await asyncio.to_thread(lambda: scale_png(path.read_bytes(), width))
            thumbs[key] = png
            while len(thumbs) > THUMB_CACHE_SIZE:
                thumbs.popitem(last=False)
        return Response(png, media_type="image/png", headers={"Cache-Control": "private, max-age=3600"})

    router.include_router(reads)
    return router


def install(app: FastAPI, orch: CellOrchestrator, guard: TokenGuard) -> None:
    """Serve the dashboard page at ``/``, its files under ``/ui/``, and its feeds."""
    app.include_router(build_router(orch, guard))
    app.mount("/ui", StaticFiles(directory=str(STATIC_DIR)), name="dashboard-ui")
