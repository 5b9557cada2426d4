"""Line rules of the ABB line protocol no other test pinned down (a mutation run found them unguarded).

Facts: a RAPID string holds at most 80 characters (``SocketReceive \\Str``; ../shared/reference/abb_comms.md
3.2, compas_rrc#16), so a line, its newline included, is at most 80 bytes (drivers/abb_robot/README.md,
"The line protocol"). The assertions are on byte counts and literal bytes, not on the codec's own objects.
"""

from __future__ import annotations

import pytest

from abb_robot import protocol as P


def test_a_line_of_exactly_80_bytes_is_sent() -> None:
    data = P.format_reply(1, P.Status.OK, "x" * 74)
    assert data == b"1 OK " + b"x" * 74 + b"\n"
    assert len(data) == 80


def test_a_line_of_81_bytes_is_refused_as_too_long() -> None:
    """79 characters and the newline fit; 80 characters and the newline are 81 bytes: one too many."""
    with pytest.raises(P.ProtocolError) as info:
        P.format_reply(1, P.Status.OK, "x" * 75)
    assert info.value.code is P.ErrorCode.TOO_LONG


def test_an_error_text_is_cut_to_fit_exactly_80_bytes() -> None:
    data = P.format_error(99999, P.ErrorCode.INTERNAL, "y" * 100)
    assert data == b"99999 ERR 199 " + b"y" * 65 + b"\n"
    assert len(data) == 80


@pytest.mark.parametrize("req_id", [0, -1, 100000])
def test_a_request_id_outside_1_to_99999_is_never_sent(req_id: int) -> None:
    """README: ``id`` 1..99999 chosen by the client; id 0 is the server's for a line it could not read
    (``0 ERR 101``), so a request under id 0 could not be told from that."""
    with pytest.raises(P.ProtocolError, match="request id"):
        P.format_request(req_id, "PING")


def test_the_first_and_last_request_ids_are_sent() -> None:
    assert P.format_request(1, "PING") == b"1 PING\n"
    assert P.format_request(99999, "PING") == b"99999 PING\n"


def test_an_error_line_of_exactly_80_characters_is_cut_to_79_and_its_newline() -> None:
    """``1 ERR 199 `` and 70 characters of text are 80 characters: with the newline 81 bytes, so one is cut."""
    data = P.format_error(1, P.ErrorCode.INTERNAL, "z" * 70)
    assert data == b"1 ERR 199 " + b"z" * 69 + b"\n"
    assert len(data) == 80
