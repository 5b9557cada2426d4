"""The service's composition roots: one per mode, each the only place its devices are built.

:func:`build_service` picks the root by ``mode``: :mod:`cellctl.service.hardware` (real drivers
only; it never imports the twin) or :mod:`cellctl.service.simulated` (the twin behind the ports).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from cellctl.config.schema import CellConfig
    from cellctl.service.compose import Service


async def build_service(config: "CellConfig", *, workdir: Path | None = None) -> "Service":
    """Build (not start) the whole cell from ``config`` with the root its ``mode`` names."""
    if config.mode == "hardware":
        from cellctl.service.hardware import build_hardware_service

        return await build_hardware_service(config, workdir=workdir)
    from cellctl.service.simulated import build_sim_service

    return await build_sim_service(config, workdir=workdir)
