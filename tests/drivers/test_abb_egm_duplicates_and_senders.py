"""EGM: copies of a session's first datagram, senders other than the controller, a stream that gets nothing.

The controller is a stand-in process (``_abb_egm_standin.py``) that answers the RAPID line protocol by hand
and sends EgmRobot datagrams encoded by hand from ABB's field numbers (``_abb_egm_wire.py``), logging each
one it sends: the samples are scored against that log. Other senders are plain UDP sockets on other
loopback addresses (127.0.0.2, 127.0.0.3).
"""

from __future__ import annotations

import asyncio
import socket
from pathlib import Path

import pytest

from _abb_egm_cell import LOOPBACK, NATTED, STRAY, check_all_sent, standin_cell, stray_sender, stream_x, until
from _abb_egm_wire import egm_robot, reply_seqno
from _abb_testkit import free_udp_port
from abb_robot import EgmPeer, EgmPeerSettings
from cellctl.ports import DeviceTimeout


@pytest.mark.parametrize("isolation", ["process", "thread"])
@pytest.mark.parametrize("fault", [("--dup", "0"), ("--late-dup", "0:20")], ids=["seqno-0-twice", "seqno-0-late"])
async def test_a_copy_of_the_streams_first_datagram_is_dropped_and_the_stream_kept(
    tmp_path: Path, fault: tuple[str, str], isolation: str
) -> None:
    async with standin_cell(tmp_path, *fault, isolation=isolation) as cell:
        got = await stream_x(cell)
        check_all_sent(got, cell.sent_x())
        peer = cell.robot.egm
        assert peer is not None and peer.stats().duplicates == 1 and peer.stats().sessions == 1


@pytest.mark.parametrize("isolation", ["process", "thread"])
async def test_a_copy_of_seqno_0_does_not_restart_a_guidance_session(isolation: str) -> None:
    peer = EgmPeer(EgmPeerSettings(port=0, bind_host=LOOPBACK, receive_timeout_s=0.3, isolation=isolation))  # type: ignore[arg-type]
    await peer.start()
    ctl = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    ctl.bind((LOOPBACK, 0))
    ctl.settimeout(2.0)

    def exchange(data: bytes) -> int | None:
        """Send one datagram; the seqno of the peer's reply (None: no reply)."""
        ctl.sendto(data, (LOOPBACK, peer.port))
        try:
            return reply_seqno(ctl.recv(4096))
        except socket.timeout:
            return None

    try:
        first = egm_robot(0, 1000, 500.0)
        replies = [await asyncio.to_thread(exchange, d) for d in (first, egm_robot(1, 1004, 500.1), egm_robot(2, 1008, 500.2))]
        assert replies == [0, 1, 2]
        ctl.settimeout(0.2)
        assert await asyncio.to_thread(exchange, first) is None  # the copy: dropped, not answered
        ctl.settimeout(2.0)
        assert await asyncio.to_thread(exchange, egm_robot(3, 1012, 500.3)) == 3  # the session goes on
        await until(lambda: peer.stats().received == 4)
        st = peer.stats()
        assert (st.sessions, st.duplicates, st.lost, st.received) == (1, 1, 0, 4)
        # The controller restarting EGM at once: seqno 0 stamped after the last datagram is a new session.
        assert await asyncio.to_thread(exchange, egm_robot(0, 1100, 510.0)) == 0
        await until(lambda: peer.stats().sessions == 2)
        assert peer.stats().sessions == 2
        await asyncio.sleep(0.5)  # silence beyond receive_timeout_s: seqno 0 then begins a session whatever it holds
        assert await asyncio.to_thread(exchange, egm_robot(0, 1100, 510.0)) == 0
        await until(lambda: peer.stats().sessions == 3)
        assert peer.stats().sessions == 3 and peer.stats().duplicates == 1
    finally:
        ctl.close()
        await peer.close()


async def test_the_robots_host_is_taken_over_a_stray_sender_that_keeps_sending(tmp_path: Path) -> None:
    async with standin_cell(tmp_path, isolation="process") as cell:
        peer = cell.robot.egm
        assert peer is not None
        with stray_sender(cell.egm_port):  # it sends first and all along
            await asyncio.sleep(0.1)
            got = await stream_x(cell)
        check_all_sent(got, cell.sent_x())
        assert peer.snapshot().controller is not None and peer.snapshot().controller[0] == LOOPBACK  # type: ignore[index]
        assert peer.stats().foreign > 50  # the stray's datagrams while the controller streamed: refused, counted
        assert cell.robot.stream_stats.received == len(got)


async def test_behind_nat_the_controller_is_taken_once_a_stray_sender_went_quiet(tmp_path: Path) -> None:
    # The controller's datagrams come from another address than its host (NAT): it cannot be preferred,
    # but a stray sender that sent first and went quiet for longer than egm_receive_timeout_s keeps no lock.
    async with standin_cell(tmp_path, "--src", NATTED) as cell:
        with stray_sender(cell.egm_port, count=5):
            pass
        peer = cell.robot.egm
        assert peer is not None
        await until(lambda: peer.stats().received == 5)
        assert peer.snapshot().controller[0] == STRAY  # type: ignore[index]  # the first sender took the lock
        await asyncio.sleep(0.8)
        got = await stream_x(cell)
        check_all_sent(got, cell.sent_x())
        assert peer.snapshot().controller[0] == NATTED  # type: ignore[index]


@pytest.mark.parametrize("isolation", ["process", "thread"])
async def test_the_controller_named_by_host_name_takes_the_lock_and_keeps_it(isolation: str) -> None:
    peer = EgmPeer(EgmPeerSettings(port=0, bind_host=LOOPBACK, receive_timeout_s=0.3, preferred_host="localhost",
                                   isolation=isolation))  # type: ignore[arg-type]
    await peer.start()
    stray = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    stray.bind((STRAY, 0))
    ctl = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    ctl.bind((LOOPBACK, 0))  # what "localhost" names
    try:
        async def settle() -> None:
            await asyncio.sleep(0.05)  # a process peer publishes its status after each batch

        stray.sendto(egm_robot(0, 1000, 0.0), (LOOPBACK, peer.port))
        await settle()
        assert peer.snapshot().controller == stray.getsockname()  # nobody else yet: the first sender is taken
        for seq in range(3):  # the controller: taken at once, the stray still sending
            ctl.sendto(egm_robot(seq, 5000 + 4 * seq, 500.0), (LOOPBACK, peer.port))
            stray.sendto(egm_robot(seq + 1, 1004 + 4 * seq, 0.0), (LOOPBACK, peer.port))
            await settle()
        assert peer.snapshot().controller == ctl.getsockname()
        assert peer.stats().foreign == 3
        await asyncio.sleep(0.5)  # the controller quiet for longer than receive_timeout_s
        stray.sendto(egm_robot(9, 1040, 0.0), (LOOPBACK, peer.port))
        await settle()
        assert peer.snapshot().controller == ctl.getsockname() and peer.stats().foreign == 4  # it heard the controller
    finally:
        stray.close()
        ctl.close()
        await peer.close()


async def test_a_stream_that_gets_no_datagram_names_the_udpuc_port_and_the_firewall(tmp_path: Path) -> None:
    async with standin_cell(tmp_path, "--udp-port", str(free_udp_port())) as cell:  # the UDPUC remote port is wrong
        await cell.robot.start_stream(timeout_s=5.0)
        assert await cell.robot.stop_stream(timeout_s=5.0) == ()  # stopped at once: nothing could come yet
        await cell.robot.start_stream(timeout_s=5.0)
        await asyncio.sleep(0.7)  # longer than egm_receive_timeout_s (0.5 s)
        with pytest.raises(DeviceTimeout, match=rf"no EGM datagram came .*STREAM 1.*UDPUC.*{cell.egm_port}.*firewall"):
            await cell.robot.stop_stream(timeout_s=5.0)
        assert len(cell.sent_x()) > 100  # the controller did send (elsewhere)
