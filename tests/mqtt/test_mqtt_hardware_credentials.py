"""MQTT credentials on a real cell (review r4, D4): no broker password without TLS, and the password file
read with the API token files' checks (mode, placeholder, length)."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest
from shared_support import run_cli

from cellctl.config import ConfigError, parse_config
from cellctl.config.mqtt import MqttConfig
from cellctl.mqtt.publication import MqttSetupError, read_password

ROOT = Path(__file__).resolve().parents[2]
HARDWARE = ROOT / "config" / "hardware.example.toml"
MQTT = '\n[mqtt]\nenabled = true\nhost = "127.0.0.1"\nusername = "glazing-1"\npassword_file = "/etc/cellctl/mqtt-password"\n'
FIT = "Zx9-kq2LmP4rT7vW1yB3nD"


def _hardware(**mqtt: object) -> dict:
    data = tomllib.loads(HARDWARE.read_text())
    data["mqtt"] = {"enabled": True, "host": "127.0.0.1", "username": "glazing-1",
                    "password_file": "/etc/cellctl/mqtt-password", **mqtt}  # fmt: skip
    return data


def test_the_loader_refuses_a_hardware_broker_password_without_tls() -> None:
    with pytest.raises(ConfigError, match=r"mqtt\.tls: .*password would cross the plant network in clear; add \[mqtt\.tls\]"):
        parse_config(_hardware(), "hardware.example.toml + [mqtt]")
    config = parse_config(_hardware(port=8883, tls={"ca_file": "/etc/cellctl/mqtt-ca.pem"}), "with [mqtt.tls]")
    assert config.mqtt.tls is not None


def test_config_check_names_mqtt_tls(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = tmp_path / "cell.toml"
    cfg.write_text(HARDWARE.read_text() + MQTT)
    rc, out, err = run_cli(capsys, "config", "check", "--config", str(cfg))
    assert rc == 2 and "mqtt.tls" in out + err and "in clear" in out + err, out + err


@pytest.mark.parametrize(
    ("text", "mode", "why"),
    [("changeme-please-0123456", 0o600, "placeholder"), ("short-pw", 0o600, "fewer than 16"), (FIT, 0o644, "every user")],
)
def test_a_weak_or_world_readable_password_file_is_refused(tmp_path: Path, text: str, mode: int, why: str) -> None:
    path = tmp_path / "mqtt-password"
    path.write_text(text + "\n")
    path.chmod(mode)
    config = MqttConfig(enabled=True, username="glazing-1", password_file=path)
    with pytest.raises(MqttSetupError, match="password_file") as err:
        read_password(config, tmp_path)
    assert why in str(err.value)
    path.chmod(0o600)
    path.write_text(FIT + "\n")
    assert read_password(config, tmp_path) == FIT
