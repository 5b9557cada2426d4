"""The retained status (online at connect, the will when the service dies uncleanly) and alarms on a real broker."""

from __future__ import annotations

import asyncio
import os
import signal
import tomllib
from pathlib import Path

from mosquitto_support import running_broker, subscribed
from mqtt_service_support import mqtt_config, topics
from service_test_support import (
    AUTH,
    api_client,
    free_port,
    running_service,
    sim_toml,
    start_serve,
    wait_up,
)

from cellctl.config import parse_config
from cellctl.domain import AlarmCode
from cellctl.mqtt import CellTopics

ISA95 = {"enterprise": "acme-rail", "site": "plant-2", "area": "body-shop", "line": "line-4", "cell": "glazing-1"}


def _serve_toml(api_port: int, broker_port: int) -> str:
    names = "\n".join(f'{k} = "{v}"' for k, v in ISA95.items())
    return sim_toml(api_port) + (
        f"\n[mqtt]\nenabled = true\nport = {broker_port}\nreconnect_min_s = 0.2\nreconnect_max_s = 1.0\n"
        f"keepalive_s = 5\n\n[mqtt.isa95]\n{names}\n"
    )


def test_status_is_online_while_connected_and_the_will_says_offline_when_the_service_is_killed(tmp_path: Path) -> None:
    with running_broker(tmp_path) as broker:
        config = tmp_path / "cell.toml"
        config.write_text(_serve_toml(free_port(), broker.port))
        cfg = parse_config(tomllib.loads(config.read_text()))
        t = CellTopics(cfg.mqtt.isa95)
        assert t.prefix == "acme-rail/plant-2/body-shop/line-4/glazing-1/cellctl"
        with subscribed(broker.port, t.status) as sub:
            proc = start_serve(config, tmp_path)
            try:
                wait_up(f"http://127.0.0.1:{cfg.api.port}", proc, tmp_path)
                sub.wait_for("status online", lambda: any(m.json()["online"] for m in sub.on(t.status)))
                os.kill(proc.pid, signal.SIGKILL)  # no clean disconnect: the broker publishes the will
                proc.wait(10)
                sub.wait_for("the will", lambda: not sub.on(t.status)[-1].json()["online"])
            finally:
                if proc.poll() is None:
                    proc.kill()
                    proc.wait(10)
            online, will = sub.on(t.status)[0].json(), sub.on(t.status)[-1].json()
            assert online["client_id"] == "cellctl-glazing-1" and online["reason"] == "connected"
            assert {"outbox_pending", "dropped_total", "dropped_results_total", "seq", "msg_id", "ts"} <= set(online)
            assert will["reason"] == "connection lost" and will["v"] == 1 and will["client_id"] == "cellctl-glazing-1"
        with subscribed(broker.port, t.status, "late-reader") as late:  # the will is retained
            late.wait_count(t.status, 1)
            assert late.received[0].retain and late.received[0].json()["online"] is False
        assert "Traceback" not in (tmp_path / "service.log").read_text()


async def test_an_alarm_raised_cleared_and_acknowledged_is_on_events_and_its_retained_topic_emptied(tmp_path: Path) -> None:
    with running_broker(tmp_path) as broker:
        config = mqtt_config(broker.port)
        t = topics(config)
        code = AlarmCode.DISK_SPACE_LOW
        with subscribed(broker.port, t.topic("alarm/#")) as sub:
            async with running_service(tmp_path, config) as service, api_client(service) as client:
                alarms = service.orchestrator.alarms
                alarm = await alarms.raise_alarm(code, source="test", detail="12 GB left")
                await asyncio.to_thread(sub.wait_count, t.alarm(code), 1)
                alarms.clear(code, source="test")
                await asyncio.to_thread(sub.wait_count, t.alarm_events, 2)
                r = await client.post(f"/alarms/{alarm.uid}/acknowledge", headers=AUTH)
                assert r.status_code == 200, r.text
                await asyncio.to_thread(sub.wait_count, t.alarm_events, 3)
                await asyncio.to_thread(sub.wait_for, "the alarm topic emptied", lambda: sub.on(t.alarm(code))[-1].payload == b"")
            events = [m.json() for m in sub.on(t.alarm_events)]
            assert [(e["event"], e["active"], e["acknowledged"]) for e in events] == [
                ("raised", True, False), ("cleared", False, False), ("acknowledged", False, True)]
            assert all(e["uid"] == alarm.uid and e["code"] == 1701 and e["name"] == "disk_space_low" for e in events)
            assert "12 GB left" in events[0]["message"] and events[0]["severity"] == "warning"
            assert events[2]["acknowledged_by"] == "operator"
            held = [m.payload for m in sub.on(t.alarm(code))]
            assert held[-1] == b"" and all(p for p in held[:-1])
        with subscribed(broker.port, t.topic("alarm/#"), "late-reader") as late:  # nothing retained is left
            await asyncio.sleep(0.5)  # retained messages arrive right after the SUBACK
            assert [m for m in late.received if m.retain and m.payload] == []


async def test_a_publisher_with_the_broker_down_stops_promptly_and_serves_status(tmp_path: Path) -> None:
    config = mqtt_config(free_port())  # nobody listens there
    async with running_service(tmp_path, config) as service, api_client(service) as client:
        status = (await client.get("/status")).json()["mqtt"]
        assert status["started"] and not status["connected"] and status["broker"].startswith("127.0.0.1:")
    assert service.stopped


def test_an_unreadable_password_file_stops_the_service_naming_the_field(tmp_path: Path) -> None:
    port = free_port()
    config = tmp_path / "cell.toml"
    config.write_text(_serve_toml(free_port(), port).replace("keepalive_s = 5\n", 'keepalive_s = 5\nusername = "cell"\npassword_file = "missing.txt"\n'))
    proc = start_serve(config, tmp_path)
    try:
        assert proc.wait(60) == 2  # a configuration problem: the deploy unit does not restart on 2
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    log = (tmp_path / "service.log").read_text()
    assert "mqtt.password_file" in log and "missing.txt" in log, log
