"""`cellctl` as an engineer types it: --version, python -m cellctl, config check, where the client calls, bad arguments."""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from importlib.metadata import version
from pathlib import Path

import numpy as np
import pytest
from shared_support import free_port, run_cli

import cellctl.cli as cli
from cellctl.cli import build_parser
from cellctl.config import load_config

ROOT = Path(__file__).resolve().parents[2]
SIM = ROOT / "config" / "sim.toml"


def _config_on_port(tmp_path: Path, port: int) -> Path:
    cfg = tmp_path / "cell.toml"
    cfg.write_text(SIM.read_text(encoding="utf-8").replace("\nport = 8080\n", f"\nport = {port}\n", 1), encoding="utf-8")
    return cfg


def test_version_comes_from_the_installed_metadata(capsys: pytest.CaptureFixture[str]) -> None:
    rc, out, _ = run_cli(capsys, "--version")
    assert rc == 0 and out.strip() == f"cellctl {version('cellctl')}"


def test_python_dash_m_cellctl_is_the_same_command() -> None:
    run = subprocess.run([sys.executable, "-m", "cellctl", "--version"], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0 and run.stdout.strip() == f"cellctl {version('cellctl')}", run.stderr


def test_config_check_summarises_a_valid_configuration(capsys: pytest.CaptureFixture[str]) -> None:
    rc, out, _ = run_cli(capsys, "config", "check", "--config", str(SIM))
    assert rc == 0
    assert out.startswith(f"OK: {SIM}") and "mode sim, cell_id cell-1" in out
    assert "http://127.0.0.1:8080/" in out and "opc.tcp://127.0.0.1:4840/cellctl" in out and "127.0.0.1:5020" in out
    # the alignment's choice of readings: robot time and predicted plane error, spots against the sweep
    assert re.search(r"stop and go: 6 spots, [\d.]+ s of robot time .*plane \+-[\d.]+ deg, \+-[\d.]+ mm", out), out
    assert re.search(r"on the move: \d+ readings along the sweep, [\d.]+ s of robot time and [\d.]+ s to read the laser.s storage out; plane \+-", out), out
    m = load_config(SIM).process.motion  # the speeds with the glass and, after the release, without it
    assert (f"with the glass {m.travel_speed_mm_s:g} mm/s and {m.speed_deg_s:g} deg/s" in out
            and f"released {m.empty_travel_speed_mm_s:g} mm/s and {m.empty_speed_deg_s:g} deg/s, out of the opening "
                f"{m.back_off_speed_mm_s:g} mm/s" in out), out  # fmt: skip
    # the sweeps on the move: the alignment's carries the glass, so no faster than its travel speed
    assert (f"the alignment sweeps at {m.travel_speed_mm_s:g} mm/s with the glass, the inspection at "
            f"{min(m.empty_travel_speed_mm_s or 0, load_config(SIM).process.align.sweep.speed_mm_s):g} mm/s" in out), out
    rc, out, _ = run_cli(capsys, "--config", str(SIM), "config", "check", "--secrets")
    assert rc == 0 and "could be read" in out


def test_config_check_says_where_this_cell_reads_the_wall(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc, out, _ = run_cli(capsys, "config", "check", "--config", str(SIM))
    assert rc == 0 and "this cell: stop and go (process.align.mode)" in out, out
    # a cell without a storing laser or a pose stream reads standing at the points teaching reads along the path
    m = re.search(r"devices that cannot \(no storing laser, or no EGM\): standing at the (\d+) points along the path that "
                  r"teaching reads, ([\d.]+) s of robot time between them", out)  # fmt: skip
    align, travel = load_config(SIM).process.align, load_config(SIM).process.motion.travel_speed_mm_s
    assert m and int(m[1]) == len(align.sweep.points_along_mm()), out
    legs = np.diff(np.asarray(align.sweep.path_mm, dtype=float), axis=0)
    assert float(m[2]) > np.linalg.norm(legs, axis=1).sum() / travel  # no faster than the path at the travel speed
    on_the_move = SIM.read_text(encoding="utf-8").replace('\nmode = "stop_and_go"', '\nmode = "on_the_fly"', 1)
    on_the_move = re.sub(r"(?m)^time_scale = .*$", "time_scale = 1.0", on_the_move, count=1)  # the fakes' real time
    (tmp_path / "otf.toml").write_text(on_the_move, encoding="utf-8")
    rc, out, _ = run_cli(capsys, "config", "check", "--config", str(tmp_path / "otf.toml"))
    assert rc == 0 and "this cell: on the move (process.align.mode)" in out, out
    hw = (ROOT / "config" / "hardware.example.toml").read_text(encoding="utf-8")
    no_egm = hw.replace("\negm_port = 6511 ", "\negm_port = 0 ", 1) + '\n[process.align]\nmode = "on_the_fly"\n'
    (tmp_path / "hw.toml").write_text(no_egm, encoding="utf-8")
    rc, out, err = run_cli(capsys, "config", "check", "--config", str(tmp_path / "hw.toml"))
    assert rc == 0, err
    assert "this cell: standing along the path (process.align.mode = 'on_the_fly', but devices.robot.egm_port = 0" in out, out


def test_config_check_names_the_bad_field_and_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(SIM.read_text(encoding="utf-8").replace("\nport = 8080\n", "\nport = 99999\n", 1), encoding="utf-8")
    rc, out, err = run_cli(capsys, "config", "check", "--config", str(bad))
    assert rc == 2 and out == "" and f"NOT OK: {bad}" in err and "api.port" in err and "Traceback" not in err


def test_config_check_secrets_reads_the_tokens(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                               monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    monkeypatch.delenv("CELLCTL_TOKEN", raising=False)
    hw = ROOT / "config" / "hardware.example.toml"
    rc, _, err = run_cli(capsys, "config", "check", "--config", str(hw), "--secrets")
    assert rc == 2 and "CELLCTL_TOKEN" in err


def test_client_commands_call_the_port_of_the_given_config(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                          monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    monkeypatch.delenv("CELLCTL_URL", raising=False)
    port = free_port()  # nobody listens: the error says where it called
    cfg = _config_on_port(tmp_path, port)
    for argv in (["--config", str(cfg), "status"], ["status", "--config", str(cfg)]):
        rc, _, err = run_cli(capsys, *argv)
        assert rc == 1 and f"http://127.0.0.1:{port}" in err and "Traceback" not in err
    other = free_port()
    monkeypatch.setenv("CELLCTL_URL", f"http://127.0.0.1:{other}")
    rc, _, err = run_cli(capsys, "--config", str(cfg), "status")
    assert rc == 1 and f"http://127.0.0.1:{other}" in err
    rc, _, err = run_cli(capsys, "--config", str(cfg), "status", "--url", "http://127.0.0.1:1")
    assert rc == 1 and "http://127.0.0.1:1" in err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["calibrate", "camera", "--views", "0"], "--views must be ≥ 1 (got 0)"),
        (["calibrate", "laser", "--poses", "-3"], "--poses must be ≥ 1 (got -3)"),
        (["calibrate", "hand-eye", "--views", "many"], "--views expected a whole number (got 'many')"),
        (["calibrate", "camera", "--view", "5"], "unrecognized arguments: --view 5"),
        (["cycle", "--count", "0"], "--count must be ≥ 1 (got 0)"),
        (["cycle", "--timeout", "-1"], "--timeout must be > 0 (got -1)"),
        (["serve", "--port", "70000"], "--port must be a TCP port, 0 to 65535 (got 70000)"),
        (["serve", "--demo-cycles", "-1"], "--demo-cycles must be ≥ 0 (got -1)"),
        (["--log-level", "loud", "status"], "invalid choice: 'loud'"),
    ],
)
def test_a_bad_argument_is_one_line_and_exit_2(argv: list[str], message: str, capsys: pytest.CaptureFixture[str]) -> None:
    rc, out, err = run_cli(capsys, *argv)
    assert rc == 2 and out == ""
    first = err.splitlines()[0]
    assert first.startswith("cellctl") and ": error: " in first and message in first, err
    assert "Traceback" not in err and "usage:" not in err


def test_a_bad_log_level_in_the_environment_is_a_usage_error(capsys: pytest.CaptureFixture[str],
                                                             monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    monkeypatch.setenv("CELLCTL_LOG_LEVEL", "loud")
    rc, _, err = run_cli(capsys, "config", "check")
    assert rc == 2 and "unknown log level 'loud'" in err


def _all_parsers(parser: argparse.ArgumentParser) -> list[argparse.ArgumentParser]:
    found = [parser]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in dict.fromkeys(action.choices.values()):
                found += _all_parsers(child)
    return found


def test_no_parser_takes_abbreviations_and_every_option_says_what_it_does() -> None:
    parsers = _all_parsers(build_parser())
    assert len(parsers) > 15
    assert all(not p.allow_abbrev for p in parsers)
    undocumented = [
        (p.prog, a.option_strings or a.dest)
        for p in parsers
        if not p.prog.startswith("cellctl bench")  # the benches' own options (not this issue's)
        for a in p._actions
        if not a.help and not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction))
    ]
    assert not undocumented


def test_teach_and_cycle_help_describe_their_options(capsys: pytest.CaptureFixture[str]) -> None:
    for argv, words in ((["teach", "--help"], ("--dry-run", "--dataset", "--workdir", "--url")),
                        (["cycle", "--help"], ("--recipe", "--count", "--timeout", "Idempotency-Key"))):  # fmt: skip
        rc, out, _ = run_cli(capsys, *argv)
        assert rc == 0 and all(w in out for w in words)
        assert "--config" in out and "--log-level" in out  # the global options after the command too


def test_default_config_falls_back_to_the_packaged_copy(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("CELLCTL_CONFIG", raising=False)
    assert cli.default_config() == SIM  # a source checkout: its config/sim.toml
    monkeypatch.setattr(cli, "_CHECKOUT_CONFIG", tmp_path / "absent.toml")
    packaged = cli.default_config()
    assert packaged == Path(cli.__file__).resolve().parent / "data" / "sim.toml"
    assert packaged.read_bytes() == SIM.read_bytes()  # one file: data/sim.toml is config/sim.toml
    monkeypatch.setenv("CELLCTL_CONFIG", str(tmp_path / "mine.toml"))
    assert cli.default_config() == tmp_path / "mine.toml"


def test_calibrate_status_without_a_set_says_where_it_looked(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                            monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("CELLCTL_WORKDIR", str(tmp_path / "cell"))
    rc, out, _ = run_cli(capsys, "--config", str(SIM), "calibrate", "status")
    assert rc == 1
    assert f"no calibration set in {tmp_path / 'cell' / 'var' / 'calibration'}" in out
    assert "0 version(s)" not in out and "CELLCTL_WORKDIR" in out


def test_serve_host_and_port_override_the_configuration(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                       monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    import cellctl.service as service
    from cellctl.service.compose import ServiceError as BuildError

    seen: dict[str, object] = {}

    async def fake_build(config: object, *, workdir: Path) -> None:
        seen.update(config=config, workdir=workdir)
        raise BuildError("stop here")

    monkeypatch.setattr(service, "build_service", fake_build)
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("CELLCTL_WORKDIR", raising=False)
    rc, _, err = run_cli(capsys, "--config", str(SIM), "serve", "--host", "0.0.0.0", "--port", "18080")
    assert rc == 1 and "stop here" in err and "Traceback" not in err
    api = seen["config"].api  # type: ignore[attr-defined]
    assert (api.host, api.port) == ("0.0.0.0", 18080) and seen["workdir"] == tmp_path.resolve()
    rc, _, _ = run_cli(capsys, "--config", str(SIM), "serve", "--port", "18081")
    assert (seen["config"].api.host, seen["config"].api.port) == ("127.0.0.1", 18081)  # type: ignore[attr-defined]


async def test_config_check_secrets_reads_the_opcua_certificates_as_serve_would(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from asyncua.crypto import cert_gen
    from cryptography.x509.oid import ExtendedKeyUsageOID

    text = SIM.read_text(encoding="utf-8")
    for default in ("\nport = 8080\n", "\nport = 5020\n"):  # listen ports nobody holds (the check tries them)
        text = text.replace(default, f"\nport = {free_port()}\n", 1)
    text = re.sub(r"\nport = 4840 ", f"\nport = {free_port()} ", text, count=1)
    users = '[[opcua.users]]\nname = "operator"\n'
    assert text.count(users) == 1 and text.count("\nallow_anonymous = true\n") == 1
    text = text.replace("\nallow_anonymous = true\n", '\nallow_anonymous = true\ntrusted_clients = "opcua/trusted"\n')
    cfg = tmp_path / "cell.toml"
    cfg.write_text(text.replace(users, '[[opcua.users]]\nname = "scada"\nrole = "viewer"\ncertificate = "opcua/scada.der"\n\n' + users),
                   encoding="utf-8")  # fmt: skip
    rc, out, err = run_cli(capsys, "config", "check", "--config", str(cfg), "--secrets", "--workdir", str(tmp_path))
    assert rc == 2 and out == "" and "Traceback" not in err, err
    assert f"opcua.users 'scada': certificate {tmp_path / 'opcua' / 'scada.der'} cannot be read" in err
    assert f"opcua.trusted_clients: {tmp_path / 'opcua' / 'trusted'} is not a folder" in err
    rc, out, err = run_cli(capsys, "config", "check", "--config", str(cfg))  # without --secrets the files are not read
    assert rc == 0, err
    (tmp_path / "opcua" / "trusted").mkdir(parents=True)
    cert = tmp_path / "opcua" / "scada.der"
    await cert_gen.setup_self_signed_certificate(tmp_path / "scada-key.pem", cert, "urn:example:scada", "localhost",
                                                 [ExtendedKeyUsageOID.CLIENT_AUTH], {"commonName": "scada"})  # fmt: skip
    (tmp_path / "opcua" / "trusted" / "scada.der").write_bytes(cert.read_bytes())
    rc, out, err = run_cli(capsys, "config", "check", "--config", str(cfg), "--secrets", "--workdir", str(tmp_path))
    assert rc == 0 and "certificate could be read" in out, err
