"""The fake controller on its own loop thread, stopped with clients connected (one in session, one waiting its turn,
as the fake serves one at a time): their sessions end on that loop, and each client sees its connection closed.
Peers: raw TCP sockets as the clients."""

from __future__ import annotations

import asyncio
import socket

from _abb_testkit import LOOPBACK, start_fake


def _closed_by_peer(client: socket.socket) -> bool:
    """The other end closed the connection: the next read finds its end (or a reset) within 2 s."""
    client.settimeout(2.0)
    try:
        while client.recv(4096):
            pass
    except TimeoutError:
        return False
    except ConnectionError:
        pass
    return True


def test_a_fake_stopped_with_clients_connected_ends_their_sessions_on_its_own_loop() -> None:
    fake = start_fake()
    assert fake.rapid_port is not None
    clients = [socket.create_connection((LOOPBACK, fake.rapid_port), timeout=5.0) for _ in range(2)]
    try:
        clients[0].sendall(b"1 HELLO 1\n")
        assert clients[0].recv(4096).startswith(b"1 OK"), "the fake did not answer HELLO"
        fake.stop_thread()
        loop, thread = fake._loop, fake._thread  # noqa: SLF001
        assert loop is not None and loop.is_closed() and thread is not None and not thread.is_alive()
        # Nothing was left pending on the closed loop, for the garbage collector to close later (its clean-up then
        # fails on the closed loop: "Task was destroyed but it is pending", "Event loop is closed").
        assert not asyncio.all_tasks(loop), asyncio.all_tasks(loop)
        assert [_closed_by_peer(c) for c in clients] == [True, True]
    finally:
        for c in clients:
            c.close()
