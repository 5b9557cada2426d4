"""`cellctl calibrate ...` with piped answers (a script's, taken in order): a line answers one prompt, and the next
line waits for the next prompt, even while the service's close of the answered prompt is still on its way (a loaded
host, a slow link). Before, the lines read meanwhile went to the answered prompt again and were lost: CI saw a value
typed for the board's square size refused as an answer to the car-body prompt before it. ``follow`` against a
stand-in service whose event stream holds each close back until the answer came and a little longer."""

from __future__ import annotations

import io
import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest

from cellctl.commissioning.terminal import follow

pytestmark = pytest.mark.timeout(60)
JOB = {"id": 3, "procedure": "camera", "state": "running"}
CAR_BODY = {"id": 1, "kind": "car_body_in_place", "text": "Bring the car body.", "value_label": None, "default": None}
BOARD = {"id": 2, "kind": "place_board", "text": "Fix the board.", "value_label": "measured square size (mm)", "default": 10.0}
CLOSE_LAG_S = 0.5  # how long the close of an answered prompt takes to come on the stream


class SlowCloseService:
    url = "http://127.0.0.1:1"
    _token = None

    def __init__(self) -> None:
        self.answers: list[tuple[int, str, float | None]] = []
        self._got = threading.Condition()

    def job(self, job_id: int) -> dict[str, Any]:
        return {**JOB, "prompt": None}

    def answer_prompt(self, job_id: int, prompt_id: int, action: str, value: float | None = None) -> dict[str, Any]:
        with self._got:
            self.answers.append((prompt_id, action, value))
            self._got.notify_all()
        return {}

    def _answer_of(self, prompt_id: int) -> dict[str, Any] | None:
        """The first answer to ``prompt_id`` (waiting up to 5 s for it), as the close event carries it."""
        with self._got:
            self._got.wait_for(lambda: any(a[0] == prompt_id for a in self.answers), timeout=5.0)
            got = [a for a in self.answers if a[0] == prompt_id]
        return {"action": got[0][1], "value": got[0][2], "actor": "operator"} if got else None

    def events(self) -> Iterator[tuple[str, dict[str, Any]]]:
        yield "status", {}  # the follower reads the job once
        for prompt in (CAR_BODY, BOARD):
            yield "prompt", {"job_id": JOB["id"], "open": True, "prompt": prompt}
            answer = self._answer_of(prompt["id"])
            time.sleep(CLOSE_LAG_S)  # the close is late: the follower has read on meanwhile
            yield "prompt", {"job_id": JOB["id"], "open": False, "prompt": prompt, "answer": answer}
        yield "job", {"job_id": JOB["id"], "state": "done"}


def test_each_piped_line_answers_the_next_prompt_though_the_last_ones_close_is_late() -> None:
    svc = SlowCloseService()
    out = io.StringIO()
    rc: list[int] = []
    stdin = io.StringIO("\n10.02\n")  # Enter for the car body, then the measured square size
    t = threading.Thread(target=lambda: rc.append(follow(svc, dict(JOB), out=out, stdin=stdin, events_client=svc)),  # type: ignore[arg-type]
                         daemon=True)  # fmt: skip
    t.start()
    t.join(20)
    assert svc.answers == [(1, "confirm", None), (2, "value", 10.02)], out.getvalue()
    assert "is not an answer" not in out.getvalue() and "not taken" not in out.getvalue(), out.getvalue()
