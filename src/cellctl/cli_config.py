"""``cellctl config check``: load and validate a configuration, say what it sets up, exit 0 (valid) or 2."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from cellctl.config import CellConfig, ConfigError, load_config
from cellctl.config.api import TokenUnavailable
from cellctl.config.devices import AbbRobotDevice, SimAbbDevice
from cellctl.config.loader import check_tokens
from cellctl.cli_args import default_workdir
from cellctl.commissioning.wall_plan import wall_plan


def _device(dev: Any) -> str:
    """One device as the summary names it: its kind and where it is reached."""
    where = [str(v) for v in (getattr(dev, "host", None), getattr(dev, "rapid_port", None), getattr(dev, "port", None),
                              getattr(dev, "serial_number", None)) if v is not None]  # fmt: skip
    return dev.kind + (f" ({':'.join(where)})" if where else "")


def summary(config: CellConfig) -> list[str]:
    """What the configuration sets up: mode, cell, the endpoints the service opens, the devices it reaches."""
    api, plc, ua, mq = config.api, config.plc, config.opcua, config.mqtt
    d = config.devices
    return [
        f"mode {config.mode}, cell_id {config.cell_id}",
        f"REST API and dashboard  http://{api.host}:{api.port}/  ({len(api.tokens)} API token(s))",
        "PLC Modbus TCP          " + (f"{plc.host}:{plc.port}, unit {plc.unit_id}" if plc.enabled else "off"),
        "OPC UA                  " + (f"opc.tcp://{ua.host}:{ua.port}{ua.path}" if ua.enabled else "off"),
        "MQTT                    " + (f"{mq.host}:{mq.port}" + (" (TLS)" if mq.tls else "") if mq.enabled else "off"),
        f"devices                 robot {_device(d.robot)}, laser {_device(d.laser)}, camera {_device(d.camera)}",
        f"calibration store       {config.calibration.directory} (relative to the service's --workdir)",
        "recipes                 " + "\n                          ".join(_recipe(config, r.name) for r in config.process.recipes),
        "robot speeds            " + _speeds(config),
    ]


def _speeds(config: CellConfig) -> str:
    """The cycle's speeds with the glass on the gripper and once it is released (process.motion)."""
    m = config.process.motion
    (held_mm_s, held_deg_s), (empty_mm_s, empty_deg_s) = m.speeds(glass_on_gripper=True), m.speeds(glass_on_gripper=False)
    return (f"with the glass {held_mm_s:g} mm/s and {held_deg_s:g} deg/s, into the opening {m.fine_speed_mm_s:g} mm/s; "
            f"released {empty_mm_s:g} mm/s and {empty_deg_s:g} deg/s, out of the opening {m.back_off_mm_s():g} mm/s "
            "(process.motion)")


def _recipe(config: CellConfig, name: str) -> str:
    """A recipe as the summary shows it: its PLC number, its opening, and the sections it sets."""
    recipe = next(r for r in config.process.recipes if r.name == name)
    o = config.for_recipe(name).layout.opening
    own = ", ".join(recipe.overrides())
    return (f"{recipe.id} {name}: opening {o.width_mm:g} x {o.height_mm:g} mm, corner radius {o.corner_radius_mm:g} mm"
            f" at {tuple(round(v, 1) for v in o.corner_position_mm)}; " + (f"its own {own}" if own else "the cell's settings"))


def wall_reading_in_use(config: CellConfig) -> str:
    """Which of the wall plan's choices this configuration's cycle makes, as far as the file tells."""
    if config.process.align.mode == "stop_and_go":
        return "this cell: stop and go (process.align.mode)"
    robot, no_egm = config.devices.robot, None
    if isinstance(robot, AbbRobotDevice) and robot.egm_port is None:
        no_egm = "devices.robot.egm_port = 0"
    elif isinstance(robot, SimAbbDevice) and not robot.egm:
        no_egm = "devices.robot.egm = false"
    if no_egm is not None:
        return f"this cell: standing along the path (process.align.mode = 'on_the_fly', but {no_egm}: the robot streams no pose)"
    return "this cell: on the move (process.align.mode), standing along the path in a cycle whose devices cannot"


def _check_files(config: CellConfig, workdir: Path) -> None:
    """The files the service reads at start beside its secrets (the OPC UA users' certificates and trusted
    clients' folder), paths taken from ``workdir`` as ``serve`` takes them; ConfigError naming each problem."""
    if not config.opcua.enabled:
        return
    from cellctl.opcua.security import file_problems  # asyncua and cryptography only when asked

    problems = file_problems(config.opcua, workdir)
    if problems:
        raise ConfigError("\n".join([f"{len(problems)} file(s) the OPC UA server reads at start (from {workdir}):",
                                     *(f"  - {p}" for p in problems)]))


def _cmd_check(args: argparse.Namespace) -> int:
    try:
        config = load_config(args.config)
        if args.secrets:
            check_tokens(config, str(args.config))
            _check_files(config, args.workdir)
    except (ConfigError, TokenUnavailable) as err:
        print(f"NOT OK: {args.config}\n{err}", file=sys.stderr)
        return 2
    print(f"OK: {args.config}")
    for line in summary(config):
        print(f"  {line}")
    try:
        plan = wall_plan(config).lines() + [wall_reading_in_use(config)]
    except ValueError as err:  # the nominal layout cannot make the plan (spots on a line are refused at load)
        plan = [f"cannot be predicted from process.align on [layout]: {err}"]
    print("  wall readings           " + "\n                          ".join(plan))
    print("  secrets                 " + ("every API token, OPC UA password and certificate could be read" if args.secrets
                                          else "not read (--secrets reads the API tokens, OPC UA passwords and certificates)"))  # fmt: skip
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add ``config check`` to cellctl's parser."""
    p = subparsers.add_parser("config", help="check a configuration file before the service uses it")
    sub = p.add_subparsers(dest="config_command", required=True, metavar="SUBCOMMAND")
    p = sub.add_parser(
        "check", help="load and validate the configuration (--config); print what it sets up, or each error by field",
        description="Exit status 0: the configuration is valid; 2: it is not (each problem names its field).",
    )  # fmt: skip
    p.add_argument("--secrets", action="store_true",
                   help="also read every API token and OPC UA password (environment variables, files) and the OPC UA "
                        "users' certificates and trusted clients' folder, as `serve` does")  # fmt: skip
    p.add_argument("--workdir", type=Path, default=default_workdir(),
                   help="where `serve --workdir` will run: relative paths are taken from it (default: $CELLCTL_WORKDIR, "
                        "else the current folder)")  # fmt: skip
    p.set_defaults(func=_cmd_check)
