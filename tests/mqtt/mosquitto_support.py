"""A real broker for the MQTT tests: Debian's mosquitto on a loopback port, and an independent subscriber.

The broker runs with persistence in a directory of its own (chowned to the ``mosquitto`` user
when the tests run as root, since mosquitto drops to that user), so a subscriber's persistent
session and the retained topics survive a restart on the same port. The subscriber is paho in
its own thread (not the service's code): a persistent session (clean_session False), QoS 1,
reconnecting by itself after a broker restart.
"""

from __future__ import annotations

import contextlib
import json
import os
import pwd
import shutil
import signal
import socket
import subprocess
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from shared_support import LOOPBACK, free_port, skip_or_fail

MOSQUITTO = "/usr/sbin/mosquitto"
INSTALL = "apt-get install -y mosquitto (Debian's broker; the tests start their own, never the system one)"
WAIT_S = 10.0


def mosquitto_path() -> str:
    """The broker's executable; skipped without it (failed on CI)."""
    path = MOSQUITTO if os.access(MOSQUITTO, os.X_OK) else shutil.which("mosquitto")
    if not path:
        skip_or_fail(f"mosquitto is not installed ({MOSQUITTO})", INSTALL)
    return str(path)


class Broker:
    """mosquitto on ``127.0.0.1:port`` with persistence; :meth:`stop` and :meth:`start` again keep the port."""

    def __init__(self, workdir: Path, port: int | None = None) -> None:
        self.exe = mosquitto_path()
        self.port = port or free_port()
        self.workdir = workdir
        self.data = Path(tempfile.mkdtemp(prefix="cellctl-mosquitto-"))  # outside pytest's root-only tree
        if os.geteuid() == 0:
            user = pwd.getpwnam("mosquitto")
            os.chown(self.data, user.pw_uid, user.pw_gid)
        self.conf = workdir / "mosquitto.conf"
        self.conf.write_text(
            f"listener {self.port} {LOOPBACK}\nallow_anonymous true\npersistence true\n"
            f"persistence_location {self.data}/\nlog_dest stderr\nlog_type error\nlog_type warning\n"
            "log_type notice\nlog_type information\n"
        )
        self.log = workdir / "mosquitto.log"
        self.proc: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        with self.log.open("ab") as log:
            self.proc = subprocess.Popen([self.exe, "-c", str(self.conf)], stdout=log, stderr=log)
        end = time.monotonic() + WAIT_S
        while True:
            with contextlib.suppress(OSError), socket.create_connection((LOOPBACK, self.port), timeout=0.5):
                return
            if self.proc.poll() is not None or time.monotonic() > end:
                self.stop()
                raise AssertionError(f"mosquitto did not listen on {self.port}:\n{self.log.read_text()}")
            time.sleep(0.02)

    def stop(self) -> None:
        """SIGTERM (the broker publishes the wills of connected clients and saves its state), then wait."""
        proc, self.proc = self.proc, None
        if proc is None or proc.poll() is not None:
            return
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(WAIT_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(WAIT_S)

    def close(self) -> None:
        self.stop()
        shutil.rmtree(self.data, ignore_errors=True)


@contextlib.contextmanager
def running_broker(workdir: Path, port: int | None = None) -> Iterator[Broker]:
    broker = Broker(workdir, port)
    broker.start()
    try:
        yield broker
    finally:
        broker.close()


@dataclass(frozen=True)
class Received:
    topic: str
    payload: bytes
    retain: bool

    def json(self) -> dict[str, Any]:
        return dict(json.loads(self.payload))


class Subscriber:
    """paho in a thread: a persistent session on ``topic`` at QoS 1, everything received kept in order."""

    def __init__(self, port: int, topic: str, client_id: str = "test-historian") -> None:
        import paho.mqtt.client as mqtt

        self.topic = topic
        self.received: list[Received] = []
        self._cond = threading.Condition()
        self._subscribed = threading.Event()
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id, clean_session=False)
        self.client.reconnect_delay_set(0.1, 0.5)
        self.client.on_connect = self._on_connect
        self.client.on_subscribe = lambda *_a: self._subscribed.set()
        self.client.on_message = self._on_message
        self.client.connect(LOOPBACK, port, keepalive=5)
        self.client.loop_start()
        assert self._subscribed.wait(WAIT_S), "the test subscriber got no SUBACK"

    def _on_connect(self, client: Any, _userdata: Any, _flags: Any, reason: Any, _props: Any = None) -> None:
        if not reason.is_failure:
            client.subscribe(self.topic, qos=1)

    def _on_message(self, _client: Any, _userdata: Any, msg: Any) -> None:
        with self._cond:
            self.received.append(Received(msg.topic, bytes(msg.payload), bool(msg.retain)))
            self._cond.notify_all()

    def on(self, topic: str) -> list[Received]:
        with self._cond:
            return [m for m in self.received if m.topic == topic]

    def wait_for(self, what: str, ok: Callable[[], bool], timeout_s: float = 30.0) -> None:
        """Until ``ok()`` holds (checked at every message), at most ``timeout_s``."""
        end = time.monotonic() + timeout_s
        with self._cond:
            while not ok():
                left = end - time.monotonic()
                assert left > 0, f"timed out waiting for {what}; received {[(m.topic, m.payload[:80]) for m in self.received]}"
                self._cond.wait(min(left, 0.2))

    def wait_count(self, topic: str, n: int, timeout_s: float = 30.0) -> list[Received]:
        self.wait_for(f"{n} message(s) on {topic}", lambda: len([m for m in self.received if m.topic == topic]) >= n, timeout_s)
        return self.on(topic)

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


@contextlib.contextmanager
def subscribed(port: int, topic: str, client_id: str = "test-historian") -> Iterator[Subscriber]:
    sub = Subscriber(port, topic, client_id)
    try:
        yield sub
    finally:
        sub.close()
