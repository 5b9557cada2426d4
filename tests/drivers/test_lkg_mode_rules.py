"""Mode-change rules of the LK-G driver no other test pinned down (a mutation run found them unguarded).

Facts (../shared/reference/keyence_lkg.md A4, A6, C5): ``Q0`` enters communication mode, ``R0`` returns
to general mode; an ``ER`` with the *status error* (01 on the LK-G3001, 51 on the LK-G5001) to either
means "already in that mode" and is harmless. Any other error code (88 timeout, 99 other, ...) is a
refusal: the mode did not change, and the call must say so rather than carry on as if it had.
The fake controller (the peer) answers the next command with the injected ``ER,<main>,<code>``.
"""

from __future__ import annotations

import pytest

from cellctl.ports import DeviceRejected
from keyence_lkg.fake import FakeLkgController
from test_lkg_driver import DIALECTS, Ramp, guarded, make_sensor


@pytest.mark.parametrize("dialect", DIALECTS)
@pytest.mark.parametrize("code", ["88", "99"])
async def test_a_refused_q0_is_an_error_not_communication_mode(dialect: str, code: str) -> None:
    with FakeLkgController(dialect, Ramp()) as fake:
        s = make_sensor(fake, exchange_timeout_s=1.0, mode_change_timeout_s=1.0)
        entered = False
        fake.inject_error(code)
        with pytest.raises(DeviceRejected) as info:
            async with s.communication_mode(timeout_s=2.0):
                entered = True
        assert info.value.code == code
        assert not entered
        assert [(e.command, e.reply) for e in fake.exchanges][0] == ("Q0", f"ER,Q0,{code}")
        assert fake.mode == "general"
        await s.close()


@pytest.mark.parametrize("dialect", DIALECTS)
async def test_q0_in_communication_mode_is_tolerated(dialect: str) -> None:
    """The status error to Q0 is the harmless case: the controller is in communication mode already."""
    with FakeLkgController(dialect, Ramp()) as fake:
        fake.set_mode("communication")
        s = make_sensor(fake, exchange_timeout_s=1.0, mode_change_timeout_s=1.0)
        async with s.communication_mode(timeout_s=2.0):
            assert fake.mode == "communication"
        status = "01" if dialect == "LK-G3001" else "51"
        assert [(e.command, e.reply) for e in fake.exchanges] == [("Q0", f"ER,Q0,{status}"), ("R0", "R0")]
        await guarded(s.read(timeout_s=1.0))
        await s.close()
