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
from cellctl.config.settings_id import recipe_settings_id
from cellctl.cli_args import default_workdir
from cellctl.folders import calibration_folder_problem
from cellctl.listen import port_problem


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
        f"REST API and dashboard  {'https' if api.tls_cert is not None else 'http'}://{api.host}:{api.port}/  "
        f"({len(api.tokens)} API token(s))",
        "API token roles         " + "\n                          ".join(api.role_notes()),
        "PLC Modbus TCP          " + (f"{plc.host}:{plc.port}, unit {plc.unit_id}; {plc.clients_note()}" if plc.enabled else "off"),
        "OPC UA                  " + (f"opc.tcp://{ua.host}:{ua.port}{ua.path}" if ua.enabled else "off"),
        "MQTT                    " + (f"{mq.host}:{mq.port}" + (" (TLS)" if mq.tls else "") if mq.enabled else "off"),
        f"devices                 robot {_device(d.robot)}, laser {_device(d.laser)}, camera {_device(d.camera)}",
        f"calibration store       {config.calibration.directory}"
        + ("" if Path(config.calibration.directory).is_absolute() else " (relative to the service's --workdir)"),
        "recipes                 " + "\n                          ".join(_recipe(config, r.name) for r in config.process.recipes),
        "robot speeds            " + _speeds(config),
    ]


def _speeds(config: CellConfig) -> str:
    """The cycle's speeds with the glass on the gripper and once it is released (process.motion)."""
    m = config.process.motion
    (held_mm_s, held_deg_s), (empty_mm_s, empty_deg_s) = m.speeds(glass_on_gripper=True), m.speeds(glass_on_gripper=False)
    held_sweep, empty_sweep = (config.process.sweep_speed_mm_s(glass_on_gripper=g) for g in (True, False))
    return (f"with the glass {held_mm_s:g} mm/s and {held_deg_s:g} deg/s, into the opening {m.fine_speed_mm_s:g} mm/s; "
            f"released {empty_mm_s:g} mm/s and {empty_deg_s:g} deg/s, out of the opening {m.back_off_mm_s():g} mm/s "
            f"(process.motion); on the move the alignment sweeps at {held_sweep:g} mm/s with the glass, the inspection "
            f"at {empty_sweep:g} mm/s (process.align.sweep.speed_mm_s {config.process.align.sweep.speed_mm_s:g}, at most "
            "the travel speed)")


def _recipe(config: CellConfig, name: str) -> str:
    """A recipe as the summary shows it: its PLC number, its opening, the sections it sets, and its settings' id (the
    records' ``recipe_settings``)."""
    recipe, view = next(r for r in config.process.recipes if r.name == name), config.for_recipe(name)
    o = view.layout.opening
    own = ", ".join(recipe.overrides())
    return (f"{recipe.id} {name}: opening {o.width_mm:g} x {o.height_mm:g} mm, corner radius {o.corner_radius_mm:g} mm"
            f" at {tuple(round(v, 1) for v in o.corner_position_mm)}; " + (f"its own {own}" if own else "the cell's settings")
            + f"; {recipe_settings_id(view)}")


def wall_reading_in_use(config: CellConfig, who: str = "this cell") -> str:
    """Which of the wall plan's choices this configuration's cycle makes (``who``'s: the cell's, a recipe's view), as far
    as the file tells."""
    if config.process.align.mode == "stop_and_go":
        return f"{who}: stop and go (process.align.mode)"
    robot, no_egm = config.devices.robot, None
    if isinstance(robot, AbbRobotDevice) and robot.egm_port is None:
        no_egm = "devices.robot.egm_port = 0"
    elif isinstance(robot, SimAbbDevice) and not robot.egm:
        no_egm = "devices.robot.egm = false"
    if no_egm is not None:
        return f"{who}: standing along the path (process.align.mode = 'on_the_fly', but {no_egm}: the robot streams no pose)"
    return f"{who}: on the move (process.align.mode), standing along the path in a cycle whose devices cannot"


def wall_readings(config: CellConfig, who: str = "this cell") -> list[str]:
    """The wall plan's lines for ``config`` (a recipe's view: its own align on its opening) and the choice in use."""
    from cellctl.commissioning.wall_plan import wall_plan  # scipy's fitting: only the commands that print the plan

    try:
        return wall_plan(config).lines() + [wall_reading_in_use(config, who)]
    except ValueError as err:  # the nominal layout cannot make the plan (spots on a line are refused at load)
        return [f"cannot be predicted from process.align on [layout]: {err}"]


def _check_files(config: CellConfig, workdir: Path) -> bool:
    """The files and folders the service reads or makes at start beside its secrets, as ``serve`` does (the same
    functions, nothing created), paths taken from ``workdir``, then its listen ports unless this configuration's service
    runs (then they are its own); ConfigError naming each problem. True when the ports were checked."""
    problems = _store_problems(config, workdir) + _mqtt_problems(config, workdir) + config.api.tls_problems(workdir)
    if (problem := calibration_folder_problem(config.calibration.directory, workdir)) is not None:
        problems.append(problem)
    if config.opcua.enabled:
        from cellctl.opcua.security import file_problems  # asyncua and cryptography only when asked

        problems += file_problems(config.opcua, workdir)
    running = _running_service(config, workdir)
    if running is not None:  # its ports are its own: checked when it is stopped
        print(f"note: the service of this configuration is running (pid {running}): its listen ports were not checked")
    else:
        problems += [p for setting, host, port in _listeners(config) if (p := port_problem(setting, host, port))]
    if problems:
        raise ConfigError("\n".join([f"{len(problems)} problem(s) `serve` would refuse at start (from {workdir}):",
                                     *(f"  - {p}" for p in problems)]))
    return running is None


def _store_path(config: CellConfig, workdir: Path) -> Path:
    db_path = Path(config.store.path)
    return db_path if db_path.is_absolute() else workdir.resolve() / db_path


def _running_service(config: CellConfig, workdir: Path) -> str | None:
    """The pid of a ``serve`` running on this configuration's store (it holds the store's lock), else None."""
    from cellctl.service.store_lock import StoreLock

    return StoreLock(_store_path(config, workdir)).holder()


def _store_problems(config: CellConfig, workdir: Path) -> list[str]:
    """The store's folder as ``serve`` makes it (make_store_folder), checked without creating it."""
    from cellctl.store.connection import StorePathError, check_store_path

    try:
        check_store_path(_store_path(config, workdir), creatable=True)
    except StorePathError as err:
        return [str(err)]
    return []


def _mqtt_problems(config: CellConfig, workdir: Path) -> list[str]:
    """The MQTT password and TLS files, read as ``serve`` reads them at start."""
    if not config.mqtt.enabled:
        return []
    from cellctl.mqtt.publication import MqttSetupError, read_password, tls_parameters

    problems: list[str] = []
    for read in (read_password, tls_parameters):
        try:
            read(config.mqtt, workdir.resolve())
        except MqttSetupError as err:
            problems.append(str(err))
    return problems


def _listeners(config: CellConfig) -> list[tuple[str, str, int]]:
    """(setting, host, port) of each server ``serve`` opens on a fixed port (0: any free one, not checked)."""
    out = [("[api] port", config.api.host, config.api.port)]
    if config.plc.enabled:
        out.append(("[plc] port", config.plc.host, config.plc.port))
    if config.opcua.enabled:
        out.append(("[opcua] port", config.opcua.host, config.opcua.port))
    return [(setting, host, port) for setting, host, port in out if port != 0]


SECRETS_READ = ("every API token, OPC UA password and certificate could be read, and the MQTT and API TLS files; the "
                "store's and the OPC UA certificate's folders can be made, and ")
PORTS_FREE = "every listen port is free now"
PORTS_NOT_CHECKED = "the listen ports were not checked (the service of this configuration runs and holds them)"


def _sim_problem(config: CellConfig, source: str) -> None:
    """What the simulated cell's root refuses beyond the file's rules (``build_sim_service``), as a ConfigError."""
    if config.mode != "sim":
        return
    from cellctl.service.simulated import fakes_out_of_time  # the twin's modules only for a simulated cell

    if (why := fakes_out_of_time(config)) is not None:
        raise ConfigError(f"{source}: 1 problem(s) in the configuration:\n  - {why}")


def _cmd_check(args: argparse.Namespace) -> int:
    ports_checked = False
    try:
        config = load_config(args.config)
        _sim_problem(config, str(args.config))
        if args.secrets:  # relative token and password files from --workdir, as serve takes them
            rooted = {"api": config.api.rooted(args.workdir), "opcua": config.opcua.rooted(args.workdir)}
            check_tokens(config.model_copy(update=rooted), str(args.config))
            ports_checked = _check_files(config, args.workdir)
    except (ConfigError, TokenUnavailable) as err:
        print(f"NOT OK: {args.config}\n{err}", file=sys.stderr)
        return 2
    print(f"OK: {args.config}")
    for line in summary(config):
        print(f"  {line}")
    print("  wall readings           " + "\n                          ".join(wall_readings(config)))
    for recipe in (r for r in config.process.recipes if r.align):  # a recipe's own spots or sweep: its own prediction
        lines = wall_readings(config.for_recipe(recipe.name), "this recipe")
        label = f"wall readings ({recipe.name})"
        head = f"{label:<23} " if len(label) < 24 else f"{label}\n                          "  # too long: a line of its own
        print(f"  {head}" + "\n                          ".join(lines))
    read = SECRETS_READ + (PORTS_FREE if ports_checked else PORTS_NOT_CHECKED)
    print("  secrets                 " + (read if args.secrets else
                                          "not read (--secrets reads the API tokens, OPC UA passwords and certificates)"))  # fmt: skip
    if config.mode == "hardware" and (warning := config.api.plain_http_warning()) is not None:
        print(f"warning: {warning}")  # serve logs it too; not refused: a TLS proxy or a closed cell network may cover it
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
                   help="also read every API token and OPC UA password (environment variables, files), the OPC UA "
                        "certificates and trusted clients' folder, the MQTT files and the API's TLS certificate and key, "
                        "check the folders the service makes (store, OPC UA certificate) and that its ports are free now, "
                        "as `serve` does at start")  # fmt: skip
    p.add_argument("--workdir", type=Path, default=default_workdir(),
                   help="where `serve --workdir` will run: relative paths are taken from it (default: $CELLCTL_WORKDIR, "
                        "else the current folder)")  # fmt: skip
    p.set_defaults(func=_cmd_check)
