"""Command rules of the LK-G driver no other test pinned down (a mutation run found them unguarded).

Facts (../shared/reference/keyence_lkg.md A3, A8, A9): the LK-G3001 has OUT1 and OUT2 (``M1``,
``M2``; ``M0`` reads both), the LK-G5001 OUT01..OUT12 (``MS,01`` .. ``MS,12``). There is no OUT 0:
on the LK-G3001 an "OUT 0" read would go out as ``M0``, the read of both OUTs.
"""

from __future__ import annotations

import pytest

from keyence_lkg import KeyenceLkgSensor
from keyence_lkg.codec import dialect_for


@pytest.mark.parametrize("dialect", ["LK-G3001", "LK-G5001"])
@pytest.mark.parametrize("out", [0, -1])
def test_there_is_no_out_zero(dialect: str, out: int) -> None:
    d = dialect_for(dialect)
    with pytest.raises(ValueError, match="OUT number"):
        d.read_output(out)
    with pytest.raises(ValueError, match="OUT number"):
        d.read_outputs((out, 1))


@pytest.mark.parametrize("dialect", ["LK-G3001", "LK-G5001"])
def test_a_sensor_on_out_zero_is_refused(dialect: str) -> None:
    with pytest.raises(ValueError, match="OUT number"):
        KeyenceLkgSensor(
            port="/dev/null", dialect=dialect, display_unit="0.001mm", reference_distance_mm=350.0,
            displacement_positive="away_from_head", output=0,
        )


def test_the_first_and_last_outs_are_written_as_the_controllers_do() -> None:
    assert dialect_for("LK-G3001").read_output(1).wire == b"M1\r"
    assert dialect_for("LK-G3001").read_output(2).wire == b"M2\r"
    assert dialect_for("LK-G5001").read_output(1).wire == b"MS,01\r"
    assert dialect_for("LK-G5001").read_output(12).wire == b"MS,12\r"
