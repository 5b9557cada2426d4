"""The fake controller's line server, spoken to byte by byte: every verb and every error reply."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator

import pytest

from _abb_testkit import LOOPBACK, free_udp_port, start_fake
from abb_robot.fake import EgmDynamics, FakeController
from cellctl.ports import CartesianPose


class Raw:
    """A bare TCP client that sends text lines and reads reply lines."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.reader, self.writer = reader, writer

    async def send(self, data: str | bytes) -> None:
        self.writer.write(data.encode() if isinstance(data, str) else data)
        await self.writer.drain()

    async def line(self, timeout: float = 3.0) -> str:
        raw = await asyncio.wait_for(self.reader.readline(), timeout)
        assert raw.endswith(b"\n") and len(raw) <= 80, raw
        return raw.decode().rstrip("\n")

    async def ask(self, line: str, n: int = 1) -> list[str]:
        await self.send(line + "\n")
        return [await self.line() for _ in range(n)]

    async def silent_for(self, seconds: float) -> bool:
        try:
            await asyncio.wait_for(self.reader.readline(), seconds)
        except asyncio.TimeoutError:
            return True
        return False


@contextlib.asynccontextmanager
async def raw_client(fake: FakeController) -> AsyncIterator[Raw]:
    reader, writer = await asyncio.open_connection(LOOPBACK, fake.rapid_port)
    try:
        yield Raw(reader, writer)
    finally:
        writer.close()


@pytest.fixture
def fake() -> FakeController:
    f = start_fake(time_scale=0.05)
    yield f
    f.stop_thread()


async def _hello(c: Raw) -> None:
    reply = (await c.ask("1 HELLO 1"))[0]
    assert reply == "1 OK 1 IRB_7600-325/3.1 fake-6.16"


async def test_handshake_is_required_and_versioned(fake: FakeController) -> None:
    async with raw_client(fake) as c:
        assert await c.ask("5 PING") == ["5 ERR 103 send HELLO first"]
        assert (await c.ask("6 HELLO 2"))[0].startswith("6 ERR 102 version 2 not supported, server speaks 1")
        assert await c.ask("7 GETJ") == ["7 ERR 103 send HELLO first"]
        await _hello(c)
        assert await c.ask("8 PING") == ["8 PONG"]


async def test_settings_verbs_and_their_errors(fake: FakeController) -> None:
    async with raw_client(fake) as c:
        await _hello(c)
        assert await c.ask("2 TOOL tool0") == ["2 OK tool0"]
        assert await c.ask("3 TOOL tNoSuch") == ["3 ERR 120 no tooldata tNoSuch"]
        assert await c.ask("4 WOBJ wobj0") == ["4 OK wobj0"]
        assert await c.ask("5 WOBJ wNoSuch") == ["5 ERR 121 no wobjdata wNoSuch"]
        assert (await c.ask("6 TOOL 1bad"))[0].startswith("6 ERR 122 ")
        assert await c.ask("7 SPEED 250 45.5") == ["7 OK 250.0 45.5"]
        assert (await c.ask("8 SPEED 0 10"))[0].startswith("8 ERR 122 speed needs")
        assert (await c.ask("9 SPEED 8000 10"))[0].startswith("9 ERR 122 ")
        assert await c.ask("10 ZONE 0") == ["10 OK 0.0"]
        assert await c.ask("11 ZONE 5.5") == ["11 OK 5.5"]
        assert (await c.ask("12 ZONE -1"))[0].startswith("12 ERR 122 zone needs")
    assert fake.robot.speed == (250.0, 45.5) and fake.robot.zone_mm == 5.5


async def test_staging_move_and_queries(fake: FakeController) -> None:
    async with raw_client(fake) as c:
        await _hello(c)
        assert await c.ask("2 MOVEL") == ["2 ERR 111 stage POS and ORI before a move"]
        assert await c.ask("3 ORI 1 0 0 0") == ["3 ERR 112 ORI needs a POS before it"]
        assert await c.ask("4 POS 2050.5 -10 1500") == ["4 OK"]
        assert (await c.ask("5 ORI 0.9 0 0.9 0"))[0].startswith("5 ERR 122 quaternion norm")
        assert await c.ask("6 ORI 0.7071068 0 0.7071068 0") == ["6 OK"]
        assert await c.ask("7 MOVEL", 2) == ["7 ACK", "7 DONE"]
        pos, ori = await c.ask("8 GETC", 2)
        assert pos.startswith("8 DATA POS 2050.") and ori.startswith("8 OK ORI 0.7071")
        x, y, z = (float(v) for v in pos.split()[3:])
        assert abs(x - 2050.5) < 0.5 and abs(y + 10) < 0.5 and abs(z - 1500) < 0.5
        assert len(ori.split()) == 7 and all(len(v.split(".")[1]) == 6 for v in ori.split()[3:])
        assert await c.ask("9 MOVEJ") == ["9 ERR 111 stage POS and ORI before a move"]  # target consumed
        joints = (await c.ask("10 GETJ"))[0].split()
        assert joints[:2] == ["10", "OK"] and len(joints) == 8
        assert all(len(v.split(".")[1]) == 4 for v in joints[2:])
        assert await c.ask("11 STATE") == ["11 OK 1 0"]
        assert await c.ask("12 STOP") == ["12 OK 0"]
        # A POS clears a staged ORI; HELLO clears both.
        await c.ask("13 POS 2000 0 1500")
        await c.ask("14 ORI 1 0 0 0")
        await c.ask("15 POS 2000 0 1500")
        assert await c.ask("16 MOVEJ") == ["16 ERR 111 stage POS and ORI before a move"]
        await c.ask("17 ORI 0.7071068 0 0.7071068 0")
        await _hello(c)
        assert await c.ask("18 MOVEJ") == ["18 ERR 111 stage POS and ORI before a move"]


async def test_unreachable_targets_are_refused_after_the_ack(fake: FakeController) -> None:
    async with raw_client(fake) as c:
        await _hello(c)
        await c.ask("2 POS 3800 0 1500")
        await c.ask("3 ORI 0.7071068 0 0.7071068 0")
        ack, err = await c.ask("4 MOVEL", 2)
        assert ack == "4 ACK" and err.startswith("4 ERR 130 wrist centre")
        await c.ask("5 POS 2000 0 1500")
        await c.ask("6 ORI 0.7071068 0 -0.7071068 0")  # tool pointing back at the robot
        ack, err = await c.ask("7 MOVEJ", 2)
        assert ack == "7 ACK" and err.startswith("7 ERR 131 axis 5")


async def test_busy_stop_and_queries_during_a_motion() -> None:
    fake = start_fake(time_scale=1.0)
    try:
        async with raw_client(fake) as c:
            await _hello(c)
            await c.ask("2 SPEED 50 30")
            await c.ask("3 POS 2100 0 1500")
            await c.ask("4 ORI 0.7071068 0 0.7071068 0")
            assert await c.ask("5 MOVEL") == ["5 ACK"]  # 100 mm at 50 mm/s: about 2 s
            assert await c.ask("6 PING") == ["6 PONG"]
            assert await c.ask("7 STATE") == ["7 OK 1 1"]
            assert await c.ask("8 SPEED 100 30") == ["8 ERR 110 SPEED refused: a motion is running"]
            assert await c.ask("9 TOOL tool0") == ["9 ERR 110 TOOL refused: a motion is running"]
            assert await c.ask("10 POS 2000 0 1500") == ["10 OK"]  # staging goes on
            assert await c.ask("11 ORI 0.7071068 0 0.7071068 0") == ["11 OK"]
            assert await c.ask("12 MOVEJ") == ["12 ERR 110 MOVEJ refused: a motion is running"]
            assert await c.ask("13 EGM 0.1 0.1 0.1") == ["13 ERR 110 EGM refused: a motion is running"]
            await asyncio.sleep(0.3)
            pos = (await c.ask("14 GETC", 2))[0]
            x_mid = float(pos.split()[3])
            assert 2000.0 < x_mid < 2100.0
            assert await c.ask("15 STOP", 2) == ["15 OK 1", "5 ERR 140 motion stopped"]
            x_end = float((await c.ask("16 GETC", 2))[0].split()[3])
            assert 2000.0 < x_end < 2099.0  # stopped short of the target
            assert await c.ask("17 STATE") == ["17 OK 1 0"]
    finally:
        fake.stop_thread()


@pytest.mark.parametrize(
    ("line", "reply"),
    [
        ("hello", "0 ERR 100 line does not start with a request id"),
        ("0 PING", "0 ERR 100 line does not start with a request id"),
        ("42", "42 ERR 100 request id without a verb"),
        ("42 FLY", "42 ERR 100 unknown verb FLY"),
        ("42 PING 1", "42 ERR 100 PING takes 0 args, got 1"),
        ("42 POS 1 2", "42 ERR 100 POS takes 3 args, got 2"),
        ("42 POS 1 2 zz", "42 ERR 100 argument 3 is not a decimal number"),
        ("42 POS 1 2 3e2", "42 ERR 100 argument 3 is not a decimal number"),
        ("42 POS 1 2 100000", "42 ERR 122 position beyond +-99999 mm"),
        ("42 EGM 0 1 1", "42 ERR 122 EGM needs band_mm>0, band_deg>0, 0<cond_s<=3600"),
        ("42 EGM 1 1 0", "42 ERR 122 EGM needs band_mm>0, band_deg>0, 0<cond_s<=3600"),
    ],
)
async def test_malformed_lines_get_a_syntax_error(fake: FakeController, line: str, reply: str) -> None:
    async with raw_client(fake) as c:
        await _hello(c)
        assert await c.ask(line) == [reply]
        assert await c.ask("43 PING") == ["43 PONG"]  # the connection goes on


async def test_framing_fragments_batches_and_overlong_lines(fake: FakeController) -> None:
    async with raw_client(fake) as c:
        for byte in b"1 HELLO 1\n":  # one byte at a time
            await c.send(bytes([byte]))
            await asyncio.sleep(0.001)
        assert (await c.line()).startswith("1 OK 1")
        await c.send("2 PING\n3 PING\n4 STATE\n")  # several lines in one segment
        assert [await c.line() for _ in range(3)] == ["2 PONG", "3 PONG", "4 OK 1 0"]
        await c.send("5 PING " + "x" * 100 + "\n6 PING\n")
        assert await c.line() == "0 ERR 101 line over 80 chars"
        assert await c.line() == "6 PONG"  # the rest of the long line was dropped, not parsed
        await c.send("7 PING\r\n")
        assert await c.line() == "7 PONG"
        await c.send(b"8 PING \xff\n")
        assert await c.line() == "0 ERR 100 line is not ASCII"


async def test_one_client_at_a_time_and_bye(fake: FakeController) -> None:
    async with raw_client(fake) as first:
        await _hello(first)
        async with raw_client(fake) as second:
            await second.send("1 HELLO 1\n")
            assert await second.silent_for(0.3)  # waiting in the backlog, unanswered
            assert await first.ask("2 BYE") == ["2 OK"]
            assert (await second.line()).startswith("1 OK 1")


async def test_egm_without_a_udpuc_device_fails_after_the_ack(fake: FakeController) -> None:
    async with raw_client(fake) as c:
        await _hello(c)
        assert await c.ask("2 EGM 0.1 0.1 0.1", 2) == ["2 ACK", "2 ERR 151 EGM setup failed: no UdpUc device"]


async def test_egm_session_with_a_silent_sensor_ends_on_the_comm_timeout() -> None:
    fake = start_fake(egm_sensor_port=free_udp_port(), egm=EgmDynamics(comm_timeout_s=0.3))
    try:
        async with raw_client(fake) as c:
            await _hello(c)
            assert await c.ask("2 EGM 0.1 0.1 0.1") == ["2 ACK"]
            err = await c.line(timeout=3.0)
            assert err.startswith("2 ERR 150 no data from the sensor for 0.3 s (41822")
        stats = fake.last_egm_stats
        assert stats is not None and stats.end == "comm_timeout"
        assert 0.3 <= stats.duration_s < 3.0 and stats.replies == 0
        assert stats.sent == pytest.approx(stats.duration_s / 0.004, rel=0.5)  # one EgmRobot per 4 ms cycle
    finally:
        fake.stop_thread()


async def test_motion_egm_state_and_internal_errors(fake: FakeController) -> None:
    async with raw_client(fake) as c:
        await _hello(c)
        fake.set_motors(False)
        await c.ask("2 POS 2050 0 1500")
        await c.ask("3 ORI 0.7071068 0 0.7071068 0")
        assert await c.ask("4 MOVEL", 2) == ["4 ACK", "4 ERR 141 motors are off"]
        assert await c.ask("5 STATE") == ["5 OK 0 0"]
        fake.set_motors(True)
        fake.robot.set_flange(CartesianPose((3900.0, 0.0, 1500.0), (0.7071068, 0.0, 0.7071068, 0.0)))
        reply = (await c.ask("6 GETJ"))[0]
        assert reply.startswith("6 ERR 199 joints unavailable")


async def test_egm_session_ends_with_code_152_on_motors_off_and_unreachable_references() -> None:
    import socket as _socket

    from abb_robot.egm import egm_pb2 as pb

    sensor = _socket.socket(_socket.AF_INET, _socket.SOCK_DGRAM)
    sensor.bind((LOOPBACK, 0))
    sensor.settimeout(1.0)
    fake = start_fake(egm_sensor_port=sensor.getsockname()[1], egm=EgmDynamics(comm_timeout_s=2.0))

    def answer(x: float) -> None:
        data, addr = sensor.recvfrom(4096)
        reply = pb.EgmSensor()
        reply.header.seqno, reply.header.mtype = 0, pb.EgmHeader.MSGTYPE_CORRECTION
        p = reply.planned.cartesian
        p.pos.x, p.pos.y, p.pos.z = x, 0.0, 1500.0
        p.orient.u0, p.orient.u1, p.orient.u2, p.orient.u3 = 0.7071068, 0.0, 0.7071068, 0.0
        sensor.sendto(reply.SerializeToString(), addr)

    try:
        async with raw_client(fake) as c:
            await _hello(c)
            assert await c.ask("2 EGM 0.1 0.1 5") == ["2 ACK"]
            await asyncio.to_thread(answer, 2000.0)
            fake.set_motors(False)
            assert (await c.line()).startswith("2 ERR 152 motors off during the EGM session")
            fake.set_motors(True)
            sensor.setblocking(False)
            while True:  # datagrams of the first session
                try:
                    sensor.recvfrom(4096)
                except BlockingIOError:
                    break
            sensor.settimeout(1.0)
            assert await c.ask("3 EGM 0.1 0.1 5") == ["3 ACK"]
            await asyncio.to_thread(answer, 4500.0)  # far outside the reach sphere
            assert (await c.line()).startswith("3 ERR 152 EGM reference refused: wrist centre")
    finally:
        sensor.close()
        fake.stop_thread()
