"""The PLC handshakes, written as sequential coroutines over the process image.

- ``CycleHandshake``: the four-way cycle handshake keyed by ``cycle_req_id`` (request -> ack/busy
  -> done with result -> request dropped -> done cleared). A repeated id never starts a second
  cycle: the stored result of that id is published again with ``replayed`` set. A refusal by the
  cell is that id's result too (the facade stores it; this side remembers it as well); only the
  interface's own codes (901-904: no definite answer) are not results. A new id written while
  ``cycle_request`` stays 1 is the next request: served once the current one has its ``done``.
- ``LatchedRequest``: a PackML command (``cntrl_cmd`` + ``cmd_change_request``) or a unit mode
  request, latched on the request word, answered with an echo, a result code and an ack.

They read the PLC block only through ``InputFeed`` and write only the ``CellImage``; ``flush``
puts the image on the wire. Every call into the cell has a timeout.
"""

from __future__ import annotations

import asyncio
import enum
import logging
import math
import time
from collections import OrderedDict
from collections.abc import Awaitable, Callable, Coroutine
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

from cellctl.cell.cancel import cancel_first
from cellctl.plc.codec import Value
from cellctl.plc.facade import (
    UINT32_MAX,
    CellFacade,
    CommandReply,
    CycleAcceptance,
    CycleOutcome,
    PlcErrorCode,
)
from cellctl.plc.process_image import CellImage, InputFeed, PlcInputs

log = logging.getLogger(__name__)

Flush = Callable[[], Awaitable[None]]
T = TypeVar("T")
E = TypeVar("E", bound=enum.IntEnum)

_CLEARED = {"busy": False, "done": False, "ok": False, "nok": False, "replayed": False,
            "request_mismatch": False, "install_started": False}


@dataclass(frozen=True)
class HandshakeTiming:
    poll_period_s: float
    """How often a running cycle's result is asked for."""
    facade_timeout_s: float
    """Longest wait for any one answer from the cell."""
    cycle_result_timeout_s: float
    """Longest wait for an accepted cycle's result."""


class _CellFailed(Exception):
    """The cell gave no usable answer; ``code`` is what the PLC is told."""

    code = PlcErrorCode.CELL_BAD_ANSWER


class _NoAnswer(_CellFailed):
    code = PlcErrorCode.CELL_NO_ANSWER


class _BadAnswer(_CellFailed):
    code = PlcErrorCode.CELL_BAD_ANSWER


async def _ask(coro: Coroutine[Any, Any, Any], timeout_s: float, what: str, expect: type[T],
               *, optional: bool = False) -> T:
    """Await one answer from the cell with a timeout, and check its type."""
    try:
        async with asyncio.timeout(timeout_s):  # in the handshake's task: a cancel at the stop leaves no error unread
            answer = await coro
    except Exception as exc:
        cancel_first(exc)  # the stop's cancel, ended by the call with its own error: nothing is told the PLC
        if isinstance(exc, TimeoutError):
            log.error("PLC interface: the cell did not answer %s within %.1f s", what, timeout_s)
        else:
            log.exception("PLC interface: the cell failed to answer %s", what)
        raise _NoAnswer(what) from None
    if not isinstance(answer, expect) and not (optional and answer is None):
        log.error("PLC interface: the cell answered %s with %r, not a %s", what, answer, expect.__name__)
        raise _BadAnswer(what)
    return answer  # type: ignore[no-any-return]


class CycleHandshake:
    """Serves ``cycle_request`` one request at a time."""

    REMEMBERED = 1024
    """Outcomes (results and refusals) kept in memory as a second guard against re-running an id."""

    def __init__(self, cell: CellFacade, feed: InputFeed, image: CellImage, flush: Flush,
                 timing: HandshakeTiming, clock: Callable[[], float] = time.monotonic) -> None:
        self._cell = cell
        self._feed = feed
        self._image = image
        self._flush = flush
        self._timing = timing
        self._clock = clock
        self._served: OrderedDict[int, CycleOutcome] = OrderedDict()
        self._idle = True

    @property
    def idle(self) -> bool:
        """No request is being served (the cell may show ``ready``)."""
        return self._idle

    async def run(self) -> None:
        while True:
            request: PlcInputs | None = await self._feed.wait_for(lambda i: i.cycle_request != 0)
            self._idle = False
            try:
                while request is not None:
                    await self._serve(request)
                    request = await self._next_after(request.cycle_req_id)
                    await self._publish(cycle_flags=_CLEARED)
            finally:
                self._idle = True

    async def _next_after(self, served_id: int) -> PlcInputs | None:
        """Wait until the PLC drops ``cycle_request`` (None) or writes another id with it still 1: that
        id is the next request, served behind this one (its ``done`` was published first)."""
        inputs = await self._feed.wait_for(lambda i: i.cycle_request == 0 or i.cycle_req_id != served_id)
        if inputs.cycle_request == 0:
            return None
        log.warning("PLC wrote cycle_req_id %d while cycle_request stayed 1 for %d: served as the next request "
                    "(the result of %d is published again if its id is repeated)", inputs.cycle_req_id, served_id,
                    served_id)
        return inputs

    async def _publish(self, **values: Value | dict[str, bool]) -> None:
        self._image.update(**values)
        await self._flush()

    async def _serve(self, request: PlcInputs) -> None:
        req_id = request.cycle_req_id
        if req_id == 0:
            log.warning("PLC requested a cycle with cycle_req_id 0; refused")
            await self._publish_error(request, PlcErrorCode.CYCLE_REQ_ID_ZERO)
            return
        t = self._timing
        try:
            stored = await _ask(self._cell.result_of(req_id), t.facade_timeout_s, f"result_of({req_id})",
                                CycleOutcome, optional=True)
        except _CellFailed as failed:
            await self._publish_error(request, failed.code)
            return
        if stored is not None and stored.req_id != req_id:
            log.error("the cell answered result_of(%d) with the result of cycle %d", req_id, stored.req_id)
            await self._publish_error(request, PlcErrorCode.CELL_BAD_ANSWER)
            return
        stored = stored if stored is not None else self._served.get(req_id)
        if stored is not None:
            mismatch = ((stored.part_id, stored.recipe_id, stored.car_body_id)
                        != (request.part_id, request.recipe_id, request.car_body_id))
            log.info("PLC repeated cycle_req_id %d: its stored result is published again%s", req_id,
                     " (the request's part, recipe or car body differ from the stored ones)" if mismatch else "")
            await self._publish_outcome(stored, replayed=True, mismatch=mismatch)
            return
        try:
            acceptance = await _ask(self._start(request), t.facade_timeout_s, f"start_cycle({req_id})",
                                    CycleAcceptance)
        except _CellFailed as failed:
            await self._publish_error(request, failed.code)
            return
        if not acceptance.accepted:
            log.warning("PLC cycle request %d (recipe_id %d, part_id %d) refused by the cell with error_code "
                        "%d: %s", req_id, request.recipe_id, request.part_id, acceptance.error_code,
                        acceptance.reason or "no reason given")
            refusal = _refusal(request, acceptance.error_code)
            self._remember(refusal)  # the id's result: a repeat republishes it and runs nothing
            await self._publish_outcome(refusal, replayed=False, mismatch=False)
            return
        await self._publish(cycle_ack_id=req_id,
                            cycle_flags={**_CLEARED, "ready": False, "busy": True})
        outcome = await self._wait_result(req_id)
        if isinstance(outcome, PlcErrorCode):
            await self._publish_error(request, outcome)
            return
        self._remember(outcome)
        await self._publish_outcome(outcome, replayed=False, mismatch=False)

    def _start(self, request: PlcInputs) -> Coroutine[Any, Any, CycleAcceptance]:
        """The facade's start_cycle, with ``car_body_id`` only when the PLC gave one (map 1.5): a facade
        written before it takes none, and then runs the cycle without it (logged)."""
        args = (request.cycle_req_id, request.recipe_id, request.part_id)
        if not request.car_body_id:
            return self._cell.start_cycle(*args)
        try:
            return self._cell.start_cycle(*args, car_body_id=request.car_body_id)
        except TypeError:
            log.error("the cell's start_cycle takes no car_body_id: cycle %d runs without car body %d",
                      request.cycle_req_id, request.car_body_id)
            return self._cell.start_cycle(*args)

    def _remember(self, outcome: CycleOutcome) -> None:
        self._served[outcome.req_id] = outcome
        self._served.move_to_end(outcome.req_id)
        while len(self._served) > self.REMEMBERED:
            self._served.popitem(last=False)

    async def _publish_outcome(self, o: CycleOutcome, *, replayed: bool, mismatch: bool) -> None:
        try:
            values = self._outcome_values(o, replayed=replayed, mismatch=mismatch)
            self._image.update(**values)
        except (TypeError, ValueError) as exc:  # e.g. a correction beyond float32
            log.error("the result of cycle %d cannot be put in the register map: %s", o.req_id, exc)
            await self._publish_error_values(o.req_id, o.recipe_id, o.part_id, o.car_body_id,
                                             PlcErrorCode.CELL_BAD_ANSWER)
            return
        await self._flush()

    async def _wait_result(self, req_id: int) -> CycleOutcome | PlcErrorCode:
        t = self._timing
        deadline = self._clock() + t.cycle_result_timeout_s
        while True:
            try:
                outcome = await _ask(self._cell.result_of(req_id), t.facade_timeout_s,
                                     f"result_of({req_id})", CycleOutcome, optional=True)
            except _NoAnswer:
                outcome = None  # logged; keep asking until the deadline
            except _BadAnswer:
                return PlcErrorCode.CELL_BAD_ANSWER
            if outcome is not None:
                if outcome.req_id != req_id:
                    log.error("the cell answered result_of(%d) with the result of cycle %d",
                              req_id, outcome.req_id)
                    return PlcErrorCode.CELL_BAD_ANSWER
                return outcome
            if self._clock() >= deadline:
                log.error("no result for cycle %d within %g s", req_id, t.cycle_result_timeout_s)
                return PlcErrorCode.RESULT_TIMEOUT
            await asyncio.sleep(t.poll_period_s)

    @staticmethod
    def _outcome_values(o: CycleOutcome, *, replayed: bool, mismatch: bool) -> dict[str, Any]:
        return dict(
            cycle_ack_id=o.req_id, result_req_id=o.req_id, result_part_id=o.part_id,
            result_recipe_id=o.recipe_id, result_car_body_id=o.car_body_id, error_code=o.error_code,
            dx_mm=o.dx_mm, dy_mm=o.dy_mm, dz_mm=o.dz_mm,
            drx_deg=math.degrees(o.drx_rad), dry_deg=math.degrees(o.dry_rad),
            drz_deg=math.degrees(o.drz_rad),
            cycle_time_ms=min(round(o.cycle_time_s * 1000.0), UINT32_MAX),
            cycle_flags={"ready": False, "busy": False, "done": True, "ok": o.ok, "nok": not o.ok,
                         "replayed": replayed, "request_mismatch": mismatch,
                         "install_started": o.install_started},
            inspection_status=o.inspection_status,
            **dict(zip(MEASURED_REGISTERS, o.measured or (0.0,) * 6)),
        )

    async def _publish_error(self, request: PlcInputs, error_code: int) -> None:
        """The interface's own error (901-904: no definite answer from the cell). Not the id's result,
        so not remembered: repeating the id asks the cell again."""
        await self._publish_error_values(request.cycle_req_id, request.recipe_id, request.part_id,
                                         request.car_body_id, error_code)

    async def _publish_error_values(self, req_id: int, recipe_id: int, part_id: int, car_body_id: int,
                                    error_code: int) -> None:
        await self._publish(
            cycle_ack_id=req_id, result_req_id=req_id, result_part_id=part_id, result_recipe_id=recipe_id,
            result_car_body_id=car_body_id,
            error_code=int(error_code), dx_mm=0.0, dy_mm=0.0, dz_mm=0.0,
            drx_deg=0.0, dry_deg=0.0, drz_deg=0.0, cycle_time_ms=0,
            cycle_flags={**_CLEARED, "ready": False, "done": True, "nok": True},
            inspection_status=0, **dict.fromkeys(MEASURED_REGISTERS, 0.0),
        )


MEASURED_REGISTERS = ("meas_dx_mm", "meas_dy_mm", "meas_dz_mm", "meas_drx_deg", "meas_dry_deg", "meas_drz_deg")
"""The registers of :attr:`CycleOutcome.measured`, in its order."""


def _refusal(request: PlcInputs, error_code: int) -> CycleOutcome:
    """A refused request as its id's outcome: nok with the code, nothing moved, no time spent."""
    return CycleOutcome(req_id=request.cycle_req_id, recipe_id=request.recipe_id, part_id=request.part_id,
                        car_body_id=request.car_body_id, ok=False, error_code=int(error_code),
                        dx_mm=0.0, dy_mm=0.0, dz_mm=0.0, drx_rad=0.0, dry_rad=0.0, drz_rad=0.0, cycle_time_s=0.0)


class LatchedRequest(Generic[E]):
    """A request word latched by a change-request flag and answered with echo, result and ack."""

    def __init__(self, *, name: str, feed: InputFeed, image: CellImage, flush: Flush,
                 request_field: str, value_field: str, ack_field: str, echo_field: str,
                 result_field: str, kind: type[E], invalid: E,
                 send: Callable[[E], Coroutine[Any, Any, CommandReply]], timeout_s: float) -> None:
        self._name = name
        self._feed = feed
        self._image = image
        self._flush = flush
        self._request_field = request_field
        self._value_field = value_field
        self._ack_field = ack_field
        self._echo_field = echo_field
        self._result_field = result_field
        self._kind = kind
        self._invalid = invalid
        self._send = send
        self._timeout_s = timeout_s

    async def run(self) -> None:
        while True:
            inputs = await self._feed.wait_for(lambda i: getattr(i, self._request_field) != 0)
            raw = int(getattr(inputs, self._value_field))
            reply = await self._handle(raw)
            self._image.update(**{self._echo_field: raw, self._result_field: int(reply), self._ack_field: 1})
            await self._flush()
            await self._feed.wait_for(lambda i: getattr(i, self._request_field) == 0)
            self._image.update(**{self._ack_field: 0})
            await self._flush()

    async def _handle(self, raw: int) -> CommandReply:
        try:
            value = self._kind(raw)
        except ValueError:
            value = self._invalid
        if value == self._invalid:
            log.warning("PLC sent %s %d, which is not a valid %s", self._name, raw, self._kind.__name__)
            return CommandReply.BAD_PARAMETER
        try:
            reply = await _ask(self._send(value), self._timeout_s, f"{self._name} {value.name}", CommandReply)
        except _CellFailed:
            return CommandReply.NO_ANSWER
        log.info("PLC %s %s: %s", self._name, value.name, reply.name)
        return reply
