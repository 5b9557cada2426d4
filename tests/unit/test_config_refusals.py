"""Settings that load but could never work are refused at load, each message naming the field and the fix.

Spots or a sweep path on one line, a standoff outside the laser head's range, two servers on one port,
true/false for a number, a [sim] table that is not a table, two API tokens with one value, an empty
listen host.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from cellctl.config import ConfigError, load_config, parse_config
from cellctl.config.loader import check_tokens

ROOT = Path(__file__).resolve().parents[2]
SIM_TOML = ROOT / "config" / "sim.toml"
SHIPPED = [SIM_TOML, ROOT / "config" / "hardware.example.toml", ROOT / "src" / "cellctl" / "data" / "sim.toml"]
SECRET = "Zx9-kq2LmP4rT7vW1yB3nD"  # a fit token (16+ characters, no placeholder)


def sim_data() -> dict:
    return tomllib.loads(SIM_TOML.read_text())


def refused(data: dict) -> str:
    with pytest.raises(ConfigError) as err:
        parse_config(data, "cell.toml")
    return str(err.value)


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: str(p.relative_to(ROOT)))
def test_the_shipped_configurations_still_load(path: Path) -> None:
    load_config(path)


# --- 1. the wall readings must span the wall in two directions


def test_spots_on_one_line_are_refused_naming_the_field_and_the_fix() -> None:
    d = sim_data()
    d["process"]["align"]["spots_mm"] = [[-1500.0, -60.0], [-1000.0, -60.0], [-500.0, -60.0], [-100.0, -60.0]]
    msg = refused(d)
    assert "process.align: spots_mm: the 4 spots lie on one line" in msg
    assert "lambda_mid/lambda_max of their spread is 0, below process.align.min_collinearity = 0.001" in msg
    assert "spread them in two directions" in msg


def test_spots_nearly_on_a_line_follow_min_collinearity() -> None:
    # Three spots 1000 mm apart along x, the middle one 10 mm off the line: centred, the spread across the
    # line is (2/3 * 100) / (2 * 1000^2) = 3.3e-5 of the spread along it, below the default 1e-3.
    d = sim_data()
    d["process"]["align"]["spots_mm"] = [[-2000.0, -60.0], [-1000.0, -50.0], [0.0, -60.0]]
    assert "spots_mm: the 3 spots lie on one line (lambda_mid/lambda_max of their spread is 3.33e-05" in refused(d)
    d["process"]["align"]["min_collinearity"] = 1e-5
    parse_config(d, "cell.toml")


@pytest.mark.parametrize("path", [
    [[-1500.0, -60.0], [-500.0, -60.0], [60.0, -60.0]],  # along the top edge only
    [[-1500.0, -60.0], [60.0, -60.0], [-1500.0, -60.0]],  # there and back along it
])  # fmt: skip
@pytest.mark.parametrize("mode", ["on_the_fly", "stop_and_go"])
def test_a_sweep_path_on_one_line_is_refused_naming_the_field(path: list, mode: str) -> None:
    d = sim_data()
    d["process"]["align"]["mode"] = mode  # wall_plan (config check) predicts both
    d["process"]["align"]["sweep"]["path_mm"] = path
    msg = refused(d)
    assert "process.align: sweep.path_mm: the path's 3 corners and legs lie on one line" in msg
    assert "spread them in two directions" in msg


def test_a_recipes_spots_on_one_line_are_refused_naming_the_recipe() -> None:
    d = sim_data()
    d["process"]["recipes"][1]["align"]["spots_mm"] = [[0.0, -60.0], [-600.0, -60.0], [-1200.0, -60.0]]
    assert "process.recipes[1] (door-window): align: spots_mm: the 3 spots lie on one line" in refused(d)


def test_config_check_refuses_spots_on_one_line_with_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from cellctl.cli import main

    text = SIM_TOML.read_text()
    old = "spots_mm = [[-1500.0, -60.0], [-500.0, -60.0], [60.0, 300.0], [60.0, 1200.0], [-1000.0, 1560.0], [-2060.0, 750.0]]"
    assert text.count(old) == 1
    cfg = tmp_path / "cell.toml"
    cfg.write_text(text.replace(old, "spots_mm = [[-1500.0, -60.0], [-1000.0, -60.0], [-500.0, -60.0]]"))
    assert main(["--config", str(cfg), "config", "check"]) == 2
    out, err = capsys.readouterr()
    assert "OK" not in out.split()[:1] and "NOT OK" in err and "process.align: spots_mm: the 3 spots lie on one line" in err


# --- 2. the alignment's standoff and range inside the laser head's


def test_a_standoff_beyond_the_heads_range_names_both_settings() -> None:
    d = sim_data()  # layout.laser_mount: 250 to 450 mm (the LK-G500)
    d["process"]["align"]["laser_standoff_mm"] = 470.0
    d["process"]["align"]["laser_range_mm"] = [250.0, 500.0]
    msg = refused(d)
    assert ("process.align.laser_standoff_mm = 470 lies outside the sensor head's measuring range, "
            "layout.laser_mount.range_min_mm = 250 to range_max_mm = 450") in msg  # fmt: skip
    assert "set the standoff inside the head's range" in msg


def test_a_shorter_head_refuses_the_standoff() -> None:
    d = sim_data()
    d["layout"]["laser_mount"]["range_max_mm"] = 300.0  # the standoff stays 350
    assert "process.align.laser_standoff_mm = 350 lies outside" in refused(d)
    assert "range_max_mm = 300" in refused(d)


def test_an_accepted_range_wider_than_the_heads_names_both_settings() -> None:
    d = sim_data()
    d["process"]["align"]["laser_range_mm"] = [100.0, 600.0]
    msg = refused(d)
    assert "process.align.laser_range_mm = [100, 600] extends beyond the sensor head's measuring range, " in msg
    assert "layout.laser_mount.range_min_mm = 250 to range_max_mm = 450" in msg


def test_a_range_inside_the_heads_loads() -> None:
    d = sim_data()
    d["process"]["align"]["laser_range_mm"] = [260.0, 440.0]
    d["process"]["align"]["laser_standoff_mm"] = 300.0
    assert parse_config(d, "cell.toml").process.align.laser_range_mm == (260.0, 440.0)


# --- 3. the servers on their own ports


@pytest.mark.parametrize(("a", "b"), [("api", "plc"), ("plc", "opcua"), ("api", "opcua")])
def test_two_servers_on_one_port_of_one_host_are_refused(a: str, b: str) -> None:
    d = sim_data()  # every server on 127.0.0.1
    d[a]["port"] = d[b]["port"] = 19360
    msg = refused(d)
    assert f"{a}.port and {b}.port are both 19360 on one address" in msg and "give each its own port" in msg


def test_every_address_clashes_with_any_host_on_its_port() -> None:
    d = sim_data()
    d["api"]["host"], d["plc"]["host"] = "0.0.0.0", "10.0.0.5"
    d["api"]["port"] = d["plc"]["port"] = 19362
    assert "api.port and plc.port are both 19362 on one address (api.host = '0.0.0.0', plc.host = '10.0.0.5'" in refused(d)


@pytest.mark.parametrize("server", ["api", "plc", "opcua"])
@pytest.mark.parametrize("host", ["", " ", " 127.0.0.1"])
def test_an_empty_listen_host_is_refused_naming_the_field(server: str, host: str) -> None:
    d = sim_data()
    d[server]["host"] = host
    msg = refused(d)
    assert f"{server}.host" in msg and "0.0.0.0 (every address)" in msg


def test_different_hosts_a_disabled_server_and_port_0_do_not_clash() -> None:
    d = sim_data()
    d["api"]["host"], d["plc"]["host"] = "127.0.0.1", "127.0.0.2"
    d["api"]["port"] = d["plc"]["port"] = 19363
    parse_config(d, "cell.toml")
    d = sim_data()
    d["opcua"]["enabled"] = False
    d["opcua"]["port"] = d["plc"]["port"]
    parse_config(d, "cell.toml")
    d = sim_data()
    d["api"]["port"] = d["plc"]["port"] = d["opcua"]["port"] = 0  # each gets a free port
    parse_config(d, "cell.toml")


# --- 4. true/false is no number


@pytest.mark.parametrize(("path", "where"), [
    (("plc", "port"), "plc.port"),
    (("api", "port"), "api.port"),
    (("process", "align", "max_rms_mm"), "process.align.max_rms_mm"),  # a constrained float (Finite, gt=0)
    (("process", "align", "sweep", "fixed_latency_s"), "process.align.sweep.fixed_latency_s"),  # float | None
    (("store", "retention", "cycles_days"), "store.retention.cycles_days"),  # a number or "forever"
])  # fmt: skip
def test_a_boolean_for_a_number_is_refused_naming_the_field(path: tuple[str, ...], where: str) -> None:
    d = sim_data()
    node = d
    for key in path[:-1]:
        node = node.setdefault(key, {})
    node[path[-1]] = True
    assert f"  - {where}: must be a number, not true/false" in refused(d)


def test_a_boolean_inside_a_list_of_numbers_is_refused_naming_the_item() -> None:
    d = sim_data()
    d["process"]["align"]["spots_mm"][0] = [True, -60.0]
    assert "  - process.align.spots_mm.0.0: must be a number, not true/false" in refused(d)


def test_a_boolean_in_a_recipe_is_refused_naming_the_recipe() -> None:
    d = sim_data()
    d["process"]["recipes"][1]["align"]["max_rms_mm"] = True
    assert "process.recipes[1] (door-window): align.max_rms_mm: must be a number, not true/false" in refused(d)


def test_boolean_fields_still_take_booleans() -> None:
    d = sim_data()
    d["plc"]["enabled"] = False
    d["plc"]["heartbeat_alarm"] = False
    d["api"]["open_reads"] = False
    cfg = parse_config(d, "cell.toml")
    assert (cfg.plc.enabled, cfg.plc.heartbeat_alarm, cfg.api.open_reads) == (False, False, False)


# --- 5. a [sim] sub-table that is not a table


@pytest.mark.parametrize("section", ["world", "robot"])
def test_a_sim_section_that_is_not_a_table_is_refused(section: str) -> None:
    d = sim_data()
    d["sim"][section] = 5
    assert f"sim.{section} = 5 is not a table: write it as a [sim.{section}] table" in refused(d)


# --- 6. each API token its own value


@pytest.mark.parametrize("field", ["token", "token_env", "token_file"])
def test_two_tokens_from_one_source_are_refused_naming_both(field: str, tmp_path: Path) -> None:
    value = {"token": SECRET, "token_env": "CELLCTL_TEST_T1", "token_file": str(tmp_path / "t")}[field]
    d = sim_data()
    d["api"]["tokens"] = [{"name": "operator", field: value}, {"name": "line-integrator", field: value}]
    msg = refused(d)
    assert f"api: tokens: 'operator' and 'line-integrator' have the same {field}" in msg
    assert SECRET not in msg  # the message never shows the secret


def test_two_tokens_whose_sources_hold_one_value_are_refused_when_read(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    from cellctl.api.auth import TokenGuard
    from cellctl.config.api import TokenUnavailable

    secret_file = tmp_path / "integrator.token"
    secret_file.write_text(SECRET + "\n")
    secret_file.chmod(0o600)
    monkeypatch.setenv("CELLCTL_TEST_T1", SECRET)
    d = sim_data()
    d["api"]["tokens"] = [{"name": "operator", "token_env": "CELLCTL_TEST_T1"},
                          {"name": "line-integrator", "token_file": str(secret_file)}]  # fmt: skip
    cfg = parse_config(d, "cell.toml")  # the values are read only when served (or checked with --secrets)
    with pytest.raises(ConfigError, match="api.tokens: 'operator' and 'line-integrator' have the same token value"):
        check_tokens(cfg, "cell.toml")
    with pytest.raises(TokenUnavailable, match="'operator' and 'line-integrator'"):
        TokenGuard(cfg.api)  # the audit log would record the integrator as the operator
