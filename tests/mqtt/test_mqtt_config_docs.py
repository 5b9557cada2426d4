"""[mqtt] refused by field name, the shipped examples load, docs/mqtt.md is current, the example client runs."""

from __future__ import annotations

import json
import random
import re
import subprocess
import sys
import tomllib
from datetime import datetime
from pathlib import Path
from typing import Any

import pytest
from mosquitto_support import running_broker
from service_test_support import ROOT, sim_config

from cellctl.config import ConfigError, parse_config
from cellctl.config.mqtt import Isa95Names, MqttConfig
from cellctl.mqtt import TOPICS, CellTopics, payloads
from cellctl.mqtt.doc import examples
from cellctl.mqtt.doc import main as doc_main
from cellctl.mqtt.publisher import backoff_s


def _config(**mqtt: Any) -> None:
    data = tomllib.loads((ROOT / "config" / "sim.toml").read_text())
    data["mqtt"] = mqtt
    parse_config(data, "cell.toml")


@pytest.mark.parametrize(
    ("name", "why"),
    [("plant/2", "'/'"), ("+", "wildcards"), ("line#4", "'#'"), ("$SYS", "starts with '$'"), ("", "is empty"),
     (" body", "white space"), ("x" * 65, "more than 64")],
)  # fmt: skip
def test_a_bad_isa95_level_is_refused_naming_the_field_and_why(name: str, why: str) -> None:
    with pytest.raises(ConfigError) as err:
        _config(enabled=True, isa95={"site": name})
    text = str(err.value)
    assert "mqtt.isa95.site" in text and why in text and "use e.g. letters" in text, text


@pytest.mark.parametrize(
    ("fields", "names"),
    [
        ({"password": "secret"}, ["mqtt.password", "password_file"]),
        ({"reconnect_min_s": 5.0, "reconnect_max_s": 1.0}, ["mqtt.reconnect_max_s", "mqtt.reconnect_min_s"]),
        ({"password_file": "/etc/cellctl/mqtt"}, ["mqtt.password_file", "mqtt.username"]),
        ({"tls": {"ca_file": "ca.pem", "cert_file": "cell.pem"}}, ["mqtt.tls", "key_file"]),
        ({"qos": 0}, ["mqtt.qos"]),
        ({"max_messages": 3}, ["mqtt.max_messages"]),
        ({"port": 0}, ["mqtt.port"]),
    ],
)
def test_other_mqtt_mistakes_name_their_fields(fields: dict[str, Any], names: list[str]) -> None:
    with pytest.raises(ConfigError) as err:
        _config(enabled=True, **fields)
    for name in names:
        assert name in str(err.value), str(err.value)


def test_publication_is_off_by_default_and_qos_is_one() -> None:
    cfg = sim_config()
    assert cfg.mqtt == MqttConfig() and not cfg.mqtt.enabled and cfg.mqtt.qos == 1
    assert cfg.mqtt.effective_client_id == "cellctl-cell-1"


def _commented_section(path: Path) -> dict[str, Any]:
    """The commented-out [mqtt] example of a shipped config, uncommented."""
    lines = path.read_text().splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("# [mqtt]"))
    block = []
    for line in lines[start:]:
        if not line.startswith("#"):
            break
        block.append(line[2:] if line.startswith("# ") else "")
    return tomllib.loads("\n".join(block))


@pytest.mark.parametrize("name", ["sim.toml", "hardware.example.toml"])
def test_the_shipped_configs_carry_a_commented_mqtt_example_that_loads(name: str) -> None:
    section = _commented_section(ROOT / "config" / name)["mqtt"]
    assert set(section["isa95"]) == {"enterprise", "site", "area", "line", "cell"}
    _config(**section)


def test_the_docs_page_is_current_and_lists_every_topic_with_an_example() -> None:
    assert doc_main(["--check", str(ROOT / "docs" / "mqtt.md")]) == 0, "run python -m cellctl.mqtt.doc --write docs/mqtt.md"
    page = (ROOT / "docs" / "mqtt.md").read_text()
    ex = examples()
    for spec in TOPICS:
        assert f"| `{spec.name}` | {'yes' if spec.retained else 'no'} |" in page and f"### `{spec.name}`" in page
        assert {"v", "ts", "msg_id"} <= set(ex[spec.name] or {})


def test_the_docs_check_says_when_the_page_is_stale(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    page = tmp_path / "mqtt.md"
    page.write_text((ROOT / "docs" / "mqtt.md").read_text().replace("| `status` | yes |", "| `status` | no |"))
    assert doc_main(["--check", str(page)]) == 1 and "--write" in capsys.readouterr().err
    assert doc_main(["--write", str(page)]) == 0 and doc_main(["--check", str(page)]) == 0


def test_topics_are_built_from_the_isa95_names() -> None:
    t = CellTopics(Isa95Names(enterprise="acme", site="s", area="a", line="l", cell="c"))
    assert t.result == "acme/s/a/l/c/cellctl/result" and t.alarm(1701) == "acme/s/a/l/c/cellctl/alarm/1701"
    assert t.is_alarm(t.alarm(1701)) and not t.is_alarm(t.alarm_events) and t.everything == "acme/s/a/l/c/cellctl/#"
    with pytest.raises(ValueError, match="'/'"):
        CellTopics(Isa95Names.model_construct(enterprise="a/b", site="s", area="a", line="l", cell="c"))


def test_payloads_carry_the_envelope_in_utc_and_refuse_naive_times() -> None:
    body = payloads.state("EXECUTE", "PRODUCTION", "NONE")
    assert body["v"] == 1 and re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z", body["ts"]) and len(body["msg_id"]) == 32
    assert json.loads(payloads.encode(body, seq=7))["seq"] == 7 and payloads.encode(None) == b""
    with pytest.raises(ValueError, match="timezone"):
        payloads.envelope(now=datetime(2026, 1, 1))


def test_the_back_off_doubles_from_the_minimum_up_to_the_maximum_with_jitter() -> None:
    rng = random.Random(1)
    for attempt, ceiling in [(0, 0.5), (1, 1.0), (3, 4.0), (6, 30.0), (60, 30.0)]:
        waits = [backoff_s(attempt, 0.5, 30.0, rng) for _ in range(50)]
        assert all(ceiling / 2 <= w <= ceiling for w in waits)


def test_the_example_subscriber_prints_a_result_from_a_real_broker(tmp_path: Path) -> None:
    import paho.mqtt.client as mqtt

    prefix = "acme/s/a/l/c/cellctl"
    body = payloads.result({"cycle_id": 5, "part_id": "P-5", "ok": True, "error_code": 0, "cycle_time_s": 1.5,
                            "measured_deviation": {"dx_mm": 0.1}})  # fmt: skip
    with running_broker(tmp_path) as broker:
        proc = subprocess.Popen(
            [sys.executable, str(ROOT / "examples" / "mqtt_subscriber.py"), "--port", str(broker.port), "--prefix", prefix,
             "--count", "1", "--timeout", "30", "--client-id", "example-test"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        try:
            assert proc.stdout is not None and "subscribed to" in proc.stdout.readline()  # blocks until it subscribed
            pub = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="test-publisher")
            pub.connect("127.0.0.1", broker.port)
            pub.loop_start()
            for _ in range(2):  # the same message twice: printed once
                pub.publish(f"{prefix}/result", payloads.encode(body, seq=1), qos=1).wait_for_publish(10)
            pub.loop_stop()
            pub.disconnect()
            out, err = proc.communicate(timeout=30)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate(timeout=10)
    assert proc.returncode == 0, err
    assert "result cycle 5 part P-5: OK  dx_mm=+0.100 (1.5 s)" in out
