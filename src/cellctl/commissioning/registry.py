"""What a commissioning job may be: the procedures (verify among them) and their options, and a job as the API shows it."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from cellctl.cell.alarm_table import ALARM_CATALOGUE
from cellctl.cell.alarms import AlarmManager
from cellctl.commissioning.plans import laser_floor_why, laser_poses_floor
from cellctl.commissioning.procedures import PROCEDURES, Procedure
from cellctl.commissioning.verify import collect_verify, compute_verify, plan_verify
from cellctl.config.calibration_procedure import HAND_EYE_METHODS, MotionSettings
from cellctl.config.schema import CellConfig
from cellctl.domain import AlarmCode
from cellctl.store import JobRecord

ALL_PROCEDURES: dict[str, Procedure] = {
    **PROCEDURES,
    "verify": Procedure(
        "verify", "verify", "revisit", ("camera", "hand_eye"),
        lambda cfg, cal, o, start, root: plan_verify(cfg, cal, start=start, store_root=root),
        collect_verify, compute_verify, records_part=False,
    ),
}


DEVICES_USED: dict[str, tuple[str, ...]] = {
    "camera": ("robot", "camera"), "hand_eye": ("robot", "camera"), "laser": ("robot", "laser"),
    "teaching": ("robot", "laser", "camera"), "pixel_map": ("robot", "camera"), "verify": ("robot", "camera", "laser"),
}
"""The devices each procedure moves or reads (:mod:`.procedures`, :mod:`.verify`): its job is refused while one is lost."""
LINK_LOST: dict[str, tuple[AlarmCode, str]] = {
    "robot": (AlarmCode.ROBOT_LOST, "the controller, its CellctlServer RAPID task and the network (devices.robot)"),
    "camera": (AlarmCode.CAMERA_LOST, "its power, cable and network, or its settings (devices.camera; its frame size "
               "against layout.camera)"),
    "laser": (AlarmCode.LASER_LOST, "its power, cable and USB serial adapter (devices.laser.port)"),
}
"""Per device: the watchdog's lost-link alarm (raised while the link is lost, cleared when it answers) and what to check."""


class JobRefused(Exception):
    """A job that cannot start (or a request about one that cannot be served); the message says why."""

    def __init__(self, message: str, *, conflict: bool = False) -> None:
        super().__init__(message)
        self.conflict = conflict  # True: the cell's state forbids it now (HTTP 409); False: a bad request (422)


def check_options(procedure: str, options: Mapping[str, Any], config: CellConfig) -> dict[str, Any]:
    """The job's options, checked; a bad one is refused naming the field and what it takes."""
    if procedure not in ALL_PROCEDURES:
        raise JobRefused(f"procedure: unknown '{procedure}'; choose one of {', '.join(ALL_PROCEDURES)}")
    allowed = set(ALL_PROCEDURES[procedure].option_names())
    out: dict[str, Any] = {}
    for key, value in options.items():
        if value is None:
            continue
        if key not in allowed:
            raise JobRefused(f"options.{key}: not an option of {procedure}; it takes {', '.join(sorted(allowed))}")
        if key == "views":
            if not isinstance(value, int) or isinstance(value, bool) or not 3 <= value <= 200:
                raise JobRefused(f"options.views: give a whole number of board views from 3 to 200, got {value!r}")
        elif key == "poses":
            lo = laser_poses_floor(config)
            if not isinstance(value, int) or isinstance(value, bool) or not lo <= value <= 5000:
                raise JobRefused(f"options.poses: give a whole number of laser poses from {lo} to 5000 "
                                 f"({laser_floor_why(config)}), got {value!r}")  # fmt: skip
        elif key == "store":
            if not isinstance(value, bool):
                raise JobRefused(f"options.store: true or false, got {value!r}")
        elif key == "method" and value not in HAND_EYE_METHODS:
            raise JobRefused(f"options.method: one of {', '.join(HAND_EYE_METHODS)}, got {value!r}")
        elif key == "recipe" and value not in config.process.recipe_names().values():
            known = ", ".join(config.process.recipe_names().values())
            raise JobRefused(f"options.recipe: one of the configured recipes ({known}; [[process.recipes]]), got {value!r}")
        out[key] = value
    return out


def check_links(procedure: str, alarms: AlarmManager) -> None:
    """Refused (409) while a device ``procedure`` uses is lost by the watchdog: named with the watchdog's last error."""
    lost = []
    for device in DEVICES_USED[procedure]:
        code, check = LINK_LOST[device]
        alarm = alarms.find_active(code, device)
        if alarm is not None:
            why = alarm.message.removeprefix(ALARM_CATALOGUE[code].text).removeprefix(": ") or "no answer"
            lost.append(f"the watchdog has lost the {device} since {alarm.raised_at:%H:%M:%S} UTC (alarm {int(code)}; "
                        f"{why}): check {check}")  # fmt: skip
    if lost:
        used = DEVICES_USED[procedure]
        uses = ", the ".join(used[:-1]) + f" and the {used[-1]}"
        raise JobRefused(f"the {procedure} job cannot start: it uses the {uses}, and " + "; ".join(lost) + ". Start it "
                         "again once `cellctl status` shows the link up (the alarm clears by itself); nothing was asked "
                         "or moved", conflict=True)  # fmt: skip


def motion_settings(config: CellConfig) -> MotionSettings:
    """The speeds and timeouts of the procedures' moves: the top of ``calibration.procedure``."""
    return config.calibration.procedure


def job_view(rec: JobRecord, live: Mapping[str, Any]) -> dict[str, Any]:
    """A job as the API and the dashboard show it."""
    return {
        "id": rec.id,
        "procedure": rec.procedure,
        "state": rec.state,
        "actor": rec.actor,
        "source": rec.source,
        "options": rec.options,
        "created_utc": rec.created_at.isoformat(),
        "finished_utc": None if rec.finished_at is None else rec.finished_at.isoformat(),
        "plan": rec.plan,
        "progress": live.get("progress") or rec.progress,
        "dataset": rec.dataset,
        "result": rec.result,
        "error": rec.error,
        "version_before": rec.version_before,
        "version_after": rec.version_after,
        "prompt": live.get("prompt"),
        "frames": live.get("frames", 0),
        "running": bool(live.get("running")),
    }

