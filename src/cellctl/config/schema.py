"""The root configuration model: one source of truth for every setting the cell reads."""

from __future__ import annotations

from typing import Literal

from pydantic import model_validator

from cellctl.config.api import ApiConfig
from cellctl.config.calibration import CalibrationConfig
from cellctl.config.cell import ProcessConfig
from cellctl.config.devices import DevicesConfig
from cellctl.config.plc import PlcConfig
from cellctl.config.store import AlarmsConfig, PackMLConfig, StoreConfig
from cellctl.config.vision import VisionConfig
from cellctl.config.sim import SimConfig
from cellctl.config.types import StrictModel

# The corner detector needs this much straight edge on each side of the rounded corner (mm).
MIN_STRAIGHT_EDGE_MM = 20.0


class CellConfig(StrictModel):
    """A whole cell: which devices, the process, and (for the simulated cell) the twin."""

    mode: Literal["sim", "hardware"] = "sim"
    process: ProcessConfig = ProcessConfig()
    devices: DevicesConfig = DevicesConfig()
    plc: PlcConfig = PlcConfig()
    store: StoreConfig = StoreConfig()
    alarms: AlarmsConfig = AlarmsConfig()
    packml: PackMLConfig = PackMLConfig()
    vision: VisionConfig = VisionConfig()
    api: ApiConfig = ApiConfig()
    calibration: CalibrationConfig = CalibrationConfig()
    sim: SimConfig = SimConfig()

    @model_validator(mode="after")
    def _devices_fit_the_mode(self) -> "CellConfig":
        if self.mode == "hardware":
            sim = [name for name in ("laser", "camera", "robot") if getattr(self.devices, name).kind.startswith("sim")]
            if sim:
                raise ValueError(
                    f"mode = \"hardware\" but devices {sim} are simulated (kind \"sim...\"): give each its real driver "
                    "(see config/hardware.example.toml), or set mode = \"sim\""
                )
            if self.calibration.source == "oracle":
                raise ValueError('calibration.source = "oracle" exists only in the simulated cell; use "set"')
        return self

    @model_validator(mode="after")
    def _roi_in_the_image(self) -> "CellConfig":
        if self.mode == "sim":
            cam = self.sim.camera.intrinsics
            self.vision.roi.check_inside(cam.width_px, cam.height_px)
        return self

    @model_validator(mode="after")
    def _corner_visible(self) -> "CellConfig":
        if self.mode != "sim":
            return self
        fov_w, fov_h = self.sim.camera.intrinsics.field_of_view_mm(self.process.working_distance_mm)
        straight = min(fov_w, fov_h) / 2.0 - self.sim.world.corner_radius_mm
        if straight < MIN_STRAIGHT_EDGE_MM:
            raise ValueError(
                f"sim.world.corner_radius_mm = {self.sim.world.corner_radius_mm:g} leaves {straight:.1f} mm "
                f"of straight edge beside the corner in the camera's {fov_w:.0f} x {fov_h:.0f} mm view at "
                f"{self.process.working_distance_mm:g} mm; the corner method needs at least "
                f"{MIN_STRAIGHT_EDGE_MM:g} mm: reduce corner_radius_mm to at most "
                f"{min(fov_w, fov_h) / 2.0 - MIN_STRAIGHT_EDGE_MM:.0f} mm or raise the working distance"
            )
        return self
