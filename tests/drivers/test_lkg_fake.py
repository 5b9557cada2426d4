"""The fake LK-G controller on the wire, without the driver: replies, mode rules, error codes."""

from __future__ import annotations

import os
import select
import time
import tty
from collections.abc import Iterator

import pytest

from cellctl.ports import LaserStatus
from keyence_lkg.fake import FakeLkgController


class RawPort:
    """The slave end of the fake's pseudo-terminal, opened by path like a serial adapter."""

    def __init__(self, path: str) -> None:
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        tty.setraw(self.fd)

    def send(self, data: bytes) -> None:
        os.write(self.fd, data)

    def line(self, timeout_s: float = 1.0) -> bytes | None:
        """The next CR-terminated line, or None if nothing complete arrives in time."""
        buf = b""
        deadline = time.monotonic() + timeout_s
        while not buf.endswith(b"\r"):
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self.fd], [], [], left)[0]:
                return None
            buf += os.read(self.fd, 1)
        return buf[:-1]

    def ask(self, text: str) -> str | None:
        self.send(text.encode("ascii") + b"\r")
        reply = self.line()
        return None if reply is None else reply.decode("ascii")

    def close(self) -> None:
        os.close(self.fd)


@pytest.fixture
def g3() -> Iterator[tuple[FakeLkgController, RawPort]]:
    sources = {1: lambda: 351.2345, 2: lambda: 349.5}
    with FakeLkgController("LK-G3001", sources, display_unit="0.0001mm") as fake:
        port = RawPort(fake.path)
        yield fake, port
        port.close()


@pytest.fixture
def g5() -> Iterator[tuple[FakeLkgController, RawPort]]:
    sources = {1: lambda: 351.2345, 2: lambda: 349.5, 3: lambda: None}
    with FakeLkgController("LK-G5001", sources, display_unit="0.001mm", out_count=3) as fake:
        port = RawPort(fake.path)
        yield fake, port
        port.close()


def test_the_link_is_a_symlink_to_a_pseudo_terminal(g3: tuple[FakeLkgController, RawPort]) -> None:
    fake, _ = g3
    assert os.path.islink(fake.path)
    assert os.path.realpath(fake.path) == fake.pty_path
    assert fake.pty_path is not None and fake.pty_path.startswith("/dev/pts/")


def test_lk_g3001_measurement_replies(g3: tuple[FakeLkgController, RawPort]) -> None:
    _, port = g3
    assert port.ask("M1") == "M1,+01.2345"
    assert port.ask("M2") == "M2,-00.5000"
    assert port.ask("M0") == "M0,+01.2345,-00.5000"
    assert port.ask("m1") == "M1,+01.2345"  # commands are case-insensitive
    port.send(b"M1\r\n")  # a stray LF is ignored
    assert port.line() == b"M1,+01.2345"


def test_lk_g5001_measurement_replies(g5: tuple[FakeLkgController, RawPort]) -> None:
    _, port = g5
    assert port.ask("MS,01") == "MS,01,+001.235"
    assert port.ask("MS,03") == "MS,03,+FFFFFFF"  # no return: far over range
    assert port.ask("MS,07") == "MS,07,XXXXXXXX"  # an OUT without a head
    assert port.ask("MM,110000000000") == "MM,110000000000,+001.235,-000.500"
    assert port.ask("MA") == "MA,+001.235,-000.500,+FFFFFFF"


@pytest.mark.parametrize(
    ("command", "reply"),
    [
        ("MX", "ER,MX,00"),  # unknown command
        ("MS,01", "ER,MS,00"),  # the LK-G5001's command does not exist on the LK-G3001
        ("M12", "ER,M12,20"),  # command length
        ("M1,1", "ER,M1,21"),  # parameter count
        ("R0", "ER,R0,01"),  # already in general mode
        ("SW,CA,3", "ER,SW,01"),  # settings need communication mode
        ("SR,CA", "ER,SR,01"),
    ],
)
def test_lk_g3001_error_replies_in_general_mode(g3: tuple[FakeLkgController, RawPort], command: str, reply: str) -> None:
    assert g3[1].ask(command) == reply


@pytest.mark.parametrize(
    ("command", "reply"),
    [
        ("MX", "ER,MX,50"),
        ("M1", "ER,M1,50"),
        ("MSS,01", "ER,MSS,60"),
        ("MS", "ER,MS,61"),
        ("MS,01,02", "ER,MS,61"),
        ("MS,13", "ER,MS,62"),
        ("MS,1", "ER,MS,62"),
        ("MM,000000000000", "ER,MM,62"),
        ("R0", "ER,R0,51"),
        ("SW,CA,3", "ER,SW,51"),
    ],
)
def test_lk_g5001_error_replies_in_general_mode(g5: tuple[FakeLkgController, RawPort], command: str, reply: str) -> None:
    assert g5[1].ask(command) == reply


def test_lk_g3001_communication_mode_rules(g3: tuple[FakeLkgController, RawPort]) -> None:
    fake, port = g3
    assert port.ask("Q0") == "Q0"
    assert fake.mode == "communication"
    assert port.ask("Q0") == "ER,Q0,01"
    assert port.ask("M1") == "ER,M1,01"  # no measuring in communication mode
    assert port.ask("SW,CA,3") == "SW,CA"
    assert port.ask("SR,CA") == "SR,CA,3"
    assert port.ask("SW,CA,6") == "ER,SW,22"  # 20 us .. 1 ms are codes 0..5
    assert port.ask("SW,CA") == "ER,SW,21"
    assert port.ask("SW,ZZ,1") == "ER,SW,22"
    assert port.ask("SW,OC,1,0,4") == "SW,OC"
    assert port.ask("SR,OC,1") == "SR,OC,1,0,4"
    assert port.ask("SW,OF,1,+010000") == "SW,OF"  # +1.0000 mm at 0.0001 mm
    assert port.ask("SR,OF,1") == "SR,OF,1,+01.0000"
    assert port.ask("R0") == "R0"
    assert port.ask("M1") == "M1,+02.2345"  # the offset is applied


def test_lk_g5001_communication_mode_rules(g5: tuple[FakeLkgController, RawPort]) -> None:
    _, port = g5
    assert port.ask("Q0") == "Q0"
    assert port.ask("Q0") == "ER,Q0,51"
    assert port.ask("MS,01") == "ER,MS,51"
    assert port.ask("MA") == "ER,MA,51"
    assert port.ask("SW,CA,8") == "SW,CA"
    assert port.ask("SW,CA,9") == "ER,SW,62"
    assert port.ask("SW,HB,M,01,2") == "SW,HB"
    assert port.ask("SR,HB,M,01") == "SR,HB,M,01,2"
    assert port.ask("SR,HB,01") == "ER,SR,61"
    assert port.ask("SW,OF,01,-000500") == "SW,OF"
    assert port.ask("R0") == "R0"
    assert port.ask("MS,01") == "MS,01,+000.735"


@pytest.mark.parametrize("dialect", ["LK-G3001", "LK-G5001"])
@pytest.mark.parametrize("code", ["88", "99"])
def test_injected_controller_errors(dialect: str, code: str) -> None:
    with FakeLkgController(dialect, lambda: 350.0) as fake:
        port = RawPort(fake.path)
        fake.inject_error(code)
        command = "M1" if dialect == "LK-G3001" else "MS,01"
        assert port.ask(command) == f"ER,{command.split(',')[0]},{code}"
        assert port.ask(command) is not None and not port.ask(command).startswith("ER")  # type: ignore[union-attr]
        with pytest.raises(ValueError, match="not an"):
            fake.inject_error("51" if dialect == "LK-G3001" else "01")
        port.close()


def test_distance_to_displacement_and_statuses() -> None:
    value: list[object] = [350.0]
    with FakeLkgController("LK-G3001", lambda: value[0], display_unit="0.001mm",
                           reference_distance_mm=350.0, measuring_range_mm=100.0) as fake:
        port = RawPort(fake.path)
        for distance, reply in [
            (350.0, "M1,+000.000"),
            (449.999, "M1,+099.999"),
            (450.5, "M1,+FFFFFFF"),
            (249.0, "M1,-FFFFFFF"),
            (None, "M1,+FFFFFFF"),
            (LaserStatus.NO_VALUE, "M1,XXXXXXXX"),
            (LaserStatus.OVER_RANGE_NEAR, "M1,-FFFFFFF"),
            (float("nan"), "ER,M1,99"),  # a broken physics callback is the controller's "other error"
        ]:
            value[0] = distance
            assert port.ask("M1") == reply, distance
        port.close()
    with FakeLkgController("LK-G3001", lambda: 340.0, reference_distance_mm=350.0,
                           displacement_positive="toward_head") as fake:
        port = RawPort(fake.path)
        assert port.ask("M1") == "M1,+010.000"
        port.close()


def test_faults_on_the_wire(g3: tuple[FakeLkgController, RawPort]) -> None:
    fake, port = g3
    fake.silence(1)
    assert port.ask("M1") is None
    assert port.ask("M1") == "M1,+01.2345"
    fake.garble("noise_line")
    port.send(b"M1\r")
    noise, reply = port.line(), port.line()
    assert noise is not None and b"M1" not in noise and reply == b"M1,+01.2345"
    fake.garble("truncate")
    port.send(b"M1\r")
    assert port.line(timeout_s=0.2) is None  # half a reply and no CR
    fake.delay(0.2)
    started = time.monotonic()
    assert port.ask("M2") is not None and port.ask("M2") is not None
    assert time.monotonic() - started >= 0.2
    fake.send_unsolicited("TG,1,+01.0000")
    assert port.line() == b"TG,1,+01.0000"


def test_vanish_and_reappear_at_the_same_path(g3: tuple[FakeLkgController, RawPort]) -> None:
    fake, port = g3
    first = fake.pty_path
    fake.vanish()
    assert not os.path.exists(fake.path)
    assert fake.pty_path is None
    fake.reappear()
    assert os.path.exists(fake.path)
    again = RawPort(fake.path)
    assert again.ask("M1") == "M1,+01.2345"
    again.close()
    assert first is not None
