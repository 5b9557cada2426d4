"""Settings rules of the ABB driver no other test pinned down (a mutation run found them unguarded).

``request_timeout_s`` bounds the wait for every answer the controller gives at once (README, "The client"):
zero, a negative or a non-finite value would make every such request fail at once or wait forever.
"""

from __future__ import annotations

import math

import pytest

from abb_robot import AbbRobotSettings

LOOPBACK = "127.0.0.1"


@pytest.mark.parametrize("value", [0.0, -1.0, math.nan, math.inf])
def test_a_request_timeout_that_is_no_positive_finite_number_is_refused(value: float) -> None:
    with pytest.raises(ValueError, match="request_timeout_s"):
        AbbRobotSettings(host=LOOPBACK, request_timeout_s=value)


def test_a_positive_request_timeout_is_kept() -> None:
    assert AbbRobotSettings(host=LOOPBACK, request_timeout_s=0.25).request_timeout_s == 0.25
