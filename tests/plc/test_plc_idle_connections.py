"""Modbus TCP connections that cost the cell a file descriptor for nothing: silent or half-open ones are closed after
``[plc] idle_timeout_s``, connections are capped per client address (the oldest unused one closed for a new one), the
OS keeps TCP keepalive on them, and the listener rests instead of spinning when the process runs out of descriptors.
Peers: raw sockets (end of stream seen by the client), pymodbus's client, ``ss`` (the kernel's socket timers) and a
served cell in a child process with a low open files limit."""

from __future__ import annotations

import asyncio
import logging
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from modbus_wire import fc3, read_answers
from plc_test_support import MemoryCell, plc_config, running_cell
from shared_support import held_open

from cellctl.config import load_config
from cellctl.plc.register_map import MAP_VERSION

ROOT = Path(__file__).resolve().parents[2]

DEADLINE_S = 20.0  # the idle timeouts below are 1.5 s; the margin is for a loaded machine
MAP_READ = (3).to_bytes(1, "big") + (4).to_bytes(1, "big") + b"".join(v.to_bytes(2, "big") for v in MAP_VERSION)


async def connect(port: int, source: str = "127.0.0.1") -> socket.socket:
    """A non-blocking client socket connected from ``source`` (the server, in this loop, accepts meanwhile)."""
    sock = socket.socket()
    sock.setblocking(False)
    try:
        sock.bind((source, 0))
        await asyncio.wait_for(asyncio.get_running_loop().sock_connect(sock, ("127.0.0.1", port)), 5.0)
    except BaseException:
        sock.close()
        raise
    return sock


async def until(predicate: Callable[[], bool], what: str, timeout_s: float = DEADLINE_S) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        await asyncio.sleep(0.1)


async def test_silent_and_half_frame_connections_are_closed_when_idle_and_a_polling_client_is_kept(
        caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING)
    async with running_cell(MemoryCell(), idle_timeout_s=1.5) as (server, plc):
        silent = [await connect(server.port) for _ in range(5)]
        half = [await connect(server.port) for _ in range(5)]
        for sock in half:
            sock.send(fc3(1, 100, 2)[:8])  # a frame's start that never ends
        reader, writer = await asyncio.open_connection("127.0.0.1", server.port)  # a client that polls
        t0 = time.monotonic()
        try:
            plc.start_heartbeat(0.2)  # pymodbus's client, writing every 0.2 s
            while any(held_open(s) for s in silent + half):
                assert time.monotonic() - t0 < DEADLINE_S, "idle connections still held open"
                writer.write(fc3(7, 100, 2))
                assert await read_answers(reader, 1) == [(7, MAP_READ)]
                await asyncio.sleep(0.3)
            writer.write(fc3(8, 100, 2))  # polled all along: kept, and still served
            assert await read_answers(reader, 1) == [(8, MAP_READ)]
            beats = plc.heartbeat
            await plc.stop_heartbeat()
            written = (await plc.read_plc_block())[0]  # the last write may have been cancelled by the stop
            assert beats > 5 and beats - 1 <= written <= beats, (beats, written)  # its connection was kept
        finally:
            writer.close()
            for sock in silent + half:
                sock.close()
    said = [r.getMessage() for r in caplog.records if "idle_timeout_s" in r.getMessage()]
    assert len(said) == 1 and "127.0.0.1" in said[0] and "1.5 s" in said[0], said  # ten closed, said once


async def test_accepted_connections_have_tcp_keepalive() -> None:
    async with running_cell(MemoryCell()) as (server, _plc):
        sock = await connect(server.port)
        try:
            await asyncio.sleep(0.3)
            out = subprocess.run(["ss", "-tnoH", "state", "established", f"( sport = :{server.port} )"],
                                 capture_output=True, text=True, check=True).stdout  # fmt: skip
            lines = out.strip().splitlines()
            assert len(lines) == 2 and all("timer:(keepalive," in line for line in lines), out  # the PLC's and this one
        finally:
            sock.close()


async def test_connections_beyond_the_cap_from_one_address_close_the_oldest_unused_one(
        caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING)
    async with running_cell(MemoryCell(), idle_timeout_s=120.0) as (server, plc):
        flood = []
        for _ in range(300):  # an HMI that opens a connection per poll and never closes them
            try:
                flood.append(await connect(server.port, "127.0.0.2"))
            except (OSError, asyncio.TimeoutError):
                break
        await asyncio.sleep(1.5)
        still = [s for s in flood if held_open(s)]
        assert 4 <= len(still) < len(flood) // 2, (len(still), len(flood))  # capped, and not at one connection
        await plc.write(recipe_id=2)  # the PLC, from another address, is served all along
        assert (await plc.read_plc_block())[5] == 2
        newcomer = await connect(server.port, "127.0.0.2")
        try:
            await until(lambda: not held_open(still[0]), "the oldest connection of 127.0.0.2 to be closed")
            loop = asyncio.get_running_loop()
            await loop.sock_sendall(newcomer, fc3(5, 100, 2))
            assert (await asyncio.wait_for(loop.sock_recv(newcomer, 100), 5.0))[7:] == MAP_READ  # and it is served
            assert all(held_open(s) for s in still[1:])  # only the oldest one went
        finally:
            newcomer.close()
            for sock in flood:
                sock.close()
    said = [r.getMessage() for r in caplog.records if r.name.startswith("cellctl.plc") and "127.0.0.2" in r.getMessage()]
    assert 1 <= len(said) <= 2, said  # a refusal and an eviction at most, not a line per connection


RESTING = """
import asyncio, os, resource, sys
sys.path.insert(0, sys.argv[1])
from plc_test_support import MemoryCell, plc_config
from cellctl.plc import PlcServer

async def main() -> None:
    loop = asyncio.get_running_loop()
    errors = []
    def handler(loop, context):
        if "out of system resource" in context.get("message", ""):
            errors.append(1)
        else:
            loop.default_exception_handler(context)
    loop.set_exception_handler(handler)
    resource.setrlimit(resource.RLIMIT_NOFILE, (128, 128))
    server = PlcServer(plc_config(heartbeat_timeout_s=30.0), MemoryCell())
    await server.start()
    held = []
    try:
        while True:
            held.append(os.open(os.devnull, os.O_RDONLY))
    except OSError:
        pass
    print(server.port, flush=True)
    release = asyncio.Event()
    loop.add_reader(0, release.set)
    await release.wait()
    loop.remove_reader(0)
    for fd in held:
        os.close(fd)
    print(len(errors), flush=True)
    await asyncio.sleep(float(sys.argv[2]))
    await server.stop()

asyncio.run(main())
"""


def test_the_listener_rests_while_descriptors_run_out_and_accepts_again_after(tmp_path: Path) -> None:
    script = tmp_path / "resting.py"
    script.write_text(RESTING)
    child = subprocess.Popen([sys.executable, str(script), str(Path(__file__).parent), "15"], stdin=subprocess.PIPE,
                             stdout=subprocess.PIPE, text=True)  # fmt: skip
    waiting: list[socket.socket] = []
    try:
        assert child.stdout is not None and child.stdin is not None
        port = int(child.stdout.readline())
        waiting = [socket.create_connection(("127.0.0.1", port), timeout=10) for _ in range(3)]  # in the backlog
        time.sleep(3.0)  # the child cannot accept them: no descriptor left
        child.stdin.write("release\n")
        child.stdin.flush()
        failed_accepts = int(child.stdout.readline())
        assert 1 <= failed_accepts <= 15, failed_accepts  # about one a second, not a busy loop
        for k, sock in enumerate(waiting):  # descriptors free again: accepted and served
            sock.sendall(fc3(k, 100, 2))
            assert sock.recv(100)[7:] == MAP_READ
    finally:
        for sock in waiting:
            sock.close()
        child.kill()
        child.wait(10)


def test_idle_timeout_must_be_longer_than_the_heartbeat_timeout() -> None:
    with pytest.raises(ValueError, match=r"plc.idle_timeout_s = 3 s is not longer than plc.heartbeat_timeout_s = 3 s"):
        plc_config(heartbeat_timeout_s=3.0, idle_timeout_s=3.0)
    with pytest.raises(ValueError, match="idle_timeout_s"):
        plc_config(idle_timeout_s=0)
    assert plc_config().idle_after_s == 60.0  # left out: 60 s, or twice a longer heartbeat timeout
    assert plc_config(heartbeat_timeout_s=60.0).idle_after_s == 120.0


def test_a_config_with_a_long_heartbeat_timeout_still_loads(tmp_path: Path) -> None:
    """A site's config from before idle_timeout_s (a PLC heartbeat timeout of 60 s or more) loads as it did."""
    text = (ROOT / "config" / "sim.toml").read_text(encoding="utf-8")
    assert "\nheartbeat_timeout_s = 3.0\n" in text
    cfg = tmp_path / "cell.toml"
    cfg.write_text(text.replace("\nheartbeat_timeout_s = 3.0\n", "\nheartbeat_timeout_s = 90.0\n", 1), encoding="utf-8")
    plc = load_config(cfg).plc
    assert plc.heartbeat_timeout_s == 90.0 and plc.idle_timeout_s is None and plc.idle_after_s == 180.0
