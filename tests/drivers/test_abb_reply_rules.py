"""Reply rules of the ABB RAPID link no other test pinned down (a mutation run found them unguarded).

Facts (drivers/abb_robot/README.md, "The line protocol", and its code table): every reply starts with the
request's id, then a status; ``ERR <code> <text>`` carries a three-digit code (100..199); a line the
server could not read is answered under id 0 (``0 ERR 101 ...``, the rest up to the newline dropped).
The controller here is a scripted TCP peer on 127.0.0.1 that writes literal bytes.
"""

from __future__ import annotations

import math

import pytest

from _abb_testkit import scripted_robot
from abb_robot import protocol as P
from cellctl.ports import DeviceProtocolError


@pytest.mark.parametrize("line", ["5 ERR 12 short code", "5 ERR 1300 long code", "5 ERR 0130 padded"])
def test_an_err_code_that_is_not_three_digits_is_malformed(line: str) -> None:
    with pytest.raises(P.ProtocolError, match="3-digit"):
        P.parse_reply(line)


def test_a_three_digit_err_code_is_read() -> None:
    reply = P.parse_reply("5 ERR 130 target outside reach")
    assert (reply.req_id, reply.error_code, reply.error_text) == (5, 130, "target outside reach")


def test_the_servers_id_0_error_is_a_reply() -> None:
    reply = P.parse_reply("0 ERR 101 line too long")
    assert (reply.req_id, reply.status, reply.error_code) == (0, P.Status.ERR, 101)



async def test_an_id_0_error_leaves_the_link_up_and_the_next_answer_is_taken() -> None:
    """``0 ERR 101`` answers a line the server could not read, no request of the client's: the link stays, and
    the answer that follows it on the wire is read."""

    def respond(rid: int, verb: str, args: list[str]) -> list[bytes] | None:
        if verb == "GETJ":
            return [b"0 ERR 101 line longer than 80 bytes\n", f"{rid} OK 10 20 30 40 50 60\n".encode()]
        return None

    async with scripted_robot(respond) as (robot, ctl):
        joints = await robot.read_joints(timeout_s=2.0)
        assert joints == pytest.approx(tuple(math.radians(v) for v in (10, 20, 30, 40, 50, 60)))
        assert robot.connections == 1 and ctl.connections == 1


async def test_an_err_reply_with_a_two_digit_code_is_a_protocol_error() -> None:
    def respond(rid: int, verb: str, args: list[str]) -> list[bytes] | None:
        if verb == "GETJ":
            return [f"{rid} ERR 13 bad code\n".encode()]
        return None

    async with scripted_robot(respond) as (robot, _):
        with pytest.raises(DeviceProtocolError, match="3-digit"):
            await robot.read_joints(timeout_s=2.0)
