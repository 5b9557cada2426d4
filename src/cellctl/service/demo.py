"""The main job on the simulated cell: bring the cell to Execute and install N windows, printing each."""

from __future__ import annotations

import uuid
from typing import TextIO

from cellctl.cell.orchestrator import CycleRefused
from cellctl.cell.packml import PackMLMachine
from cellctl.cell.tags import TO_EXECUTE
from cellctl.domain import PackMLState
from cellctl.service.compose import Service
from cellctl.store import CycleRequest

_SETTLED = {PackMLState.ABORTED, PackMLState.STOPPED, PackMLState.IDLE, PackMLState.EXECUTE, PackMLState.COMPLETE,
            PackMLState.HELD, PackMLState.SUSPENDED}  # fmt: skip


async def _to_execute(machine: PackMLMachine) -> None:
    while machine.state is not PackMLState.EXECUTE:
        plan = TO_EXECUTE.get(machine.state)
        cmd = plan[0] if plan else None
        if cmd is None:
            raise RuntimeError(f"the demo cannot bring the cell from {machine.state.name} to EXECUTE")
        await machine.command(cmd, actor="demo", source="cellctl serve --demo-cycles")
        await machine.wait_for_state(*_SETTLED, timeout_s=30.0)


async def run_demo(service: Service, cycles: int, out: TextIO) -> int:
    """Install ``cycles`` windows on the running service; returns how many failed."""
    orch = service.orchestrator
    if service.commissioning is not None:
        print("demo: the simulated cell commissions itself first (camera, hand-eye, laser, then teaching and nine-point "
              "for each recipe; "
              "the simulated operator answers the prompts; about a minute) ...", file=out, flush=True)  # fmt: skip
        await service.ready_for_production()
        for rec in reversed(await service.store.jobs(limit=10)):
            if rec.result and rec.state == "done":
                print(f"  job {rec.id} {rec.procedure}: {(rec.result.get('summary') or [''])[-1]}", file=out)
    await _to_execute(orch.machine)
    recipes = [r.name for r in service.config.process.recipes]
    tol = service.config.process.tolerance
    print(f"demo: {cycles} cycles, recipes {', '.join(recipes)} in turn, tolerance +-{tol.position_mm} mm / "
          f"+-{tol.orientation_deg} deg", file=out)  # fmt: skip
    print(f"{'cycle':>5} {'recipe':12} {'state':8} {'time s':>6}  {'':9}{'dX dY dZ mm':33}  dRx dRy dRz deg", file=out)
    failed = 0
    for k in range(cycles):
        recipe = recipes[k % len(recipes)]
        try:
            sub = await orch.submit_cycle(
                CycleRequest(recipe, f"demo-{k + 1}", None, source="demo"), scope="demo", key=uuid.uuid4().hex, actor="demo"
            )
        except CycleRefused as err:
            print(f"demo: stopped before cycle {k + 1}: {err.reason}", file=out)
            return cycles - k + failed
        rec = await orch.wait_cycle(sub.cycle.id, 600.0)
        res = rec.result or {}
        e = rec.true_error or {}
        ok = rec.state.value == "done"
        failed += not ok
        m = res.get("measured_deviation") or {}
        if ok and (e or m):
            rows = [("measured", m), ("true", e)]
            err = "\n".join(
                f"{'' if i == 0 else ' ' * 36}{name:9}" + f"{d['dx_mm']:+.3f} {d['dy_mm']:+.3f} {d['dz_mm']:+.3f}".ljust(33)
                + f"  {d['drx_deg']:+.4f} {d['dry_deg']:+.4f} {d['drz_deg']:+.4f}"
                for i, (name, d) in enumerate(r for r in rows if r[1])
            )
            if res.get("part_ok") is False:
                err += f"\n{' ' * 36}part NOT OK: {res.get('not_ok_reason')}"
        else:
            err = rec.error or "-"
        print(f"{rec.id:>5} {recipe:12.12} {rec.state.value:8} {res.get('cycle_time_s', 0.0):6.2f}  {err}", file=out)
    print(f"demo: {cycles - failed} of {cycles} installed; cycle records at GET /cycles", file=out)
    return failed
