"""examples/plc_handshake.st, FB_CellHandshake's cycle part, followed scan by scan (IEC 61131-3 TON: Q stays TRUE
while IN stays TRUE; only IN = FALSE resets it). The block promises that after a cycle timeout "step 0 asks for the
same id again, which waits for the same cycle's result". When step 0 re-sent in the very scan after the timeout,
CycleTimer never saw IN = FALSE: every later scan set cycle_request 1 and the timeout branch dropped it again, so the
block never asked again, never read the result and (InFlight set) never took a new request. The re-send now waits
for NOT CycleTimer.Q. No ST runtime is installed: the steps below are the block's own, checked against its text.
"""
from __future__ import annotations

import re
from pathlib import Path

ST = (Path(__file__).resolve().parents[2] / "examples" / "plc_handshake.st").read_text()


class TON:
    def __init__(self, pt: float) -> None:
        self.pt, self.q, self.start = pt, False, None

    def __call__(self, IN: bool, now: float) -> bool:  # noqa: N803 (the block's name)
        if not IN:
            self.q, self.start = False, None
        else:
            if self.start is None:
                self.start = now
            self.q = now - self.start >= self.pt
        return self.q


def test_the_example_cycle_handshake_asks_again_after_a_timeout() -> None:
    # the text this transliteration follows (guards against testing a different block)
    assert "IF InFlight AND CellAlive AND NOT CycleTimer.Q THEN" in ST
    assert re.search(r"CycleBusy := CycleStep <> 0;\s*CycleTimer\(IN := CycleBusy, PT := CycleTimeout\);\s*"
                     r"IF CycleTimer.Q THEN", ST)
    scan_s, timeout_s, cycle_s = 0.01, 1.0, 1.5  # the cell's cycle takes longer than the PLC's CycleTimeout
    plc = {"cycle_request": 0, "cycle_req_id": 0}
    cell = {"done": False, "ack": 0, "started": None}
    CycleStep, InFlight, ReqId, NextReqId = 0, False, 0, 1
    timer = TON(timeout_s)
    requests_seen_after_timeout, result_read, timed_out_at = 0, False, None
    edge_once = True
    now = 0.0
    for _ in range(int(6.0 / scan_s)):
        now += scan_s
        # the cell (one request id, its cycle done cycle_s after it was first requested)
        if plc["cycle_request"] and plc["cycle_req_id"]:
            if cell["started"] is None:
                cell["started"] = now
            cell["ack"] = plc["cycle_req_id"]
            if now - cell["started"] >= cycle_s:
                cell["done"] = True
            if timed_out_at is not None:
                requests_seen_after_timeout += 1
        elif cell["done"]:
            cell["done"] = False  # done is cleared once cycle_request = 0
        Flags_done, CellAlive, Ready = cell["done"], True, not cell["done"]
        CycleEdge = edge_once
        edge_once = False
        # --- FB_CellHandshake, cycle part ---
        if CycleStep == 0:
            SendRequest = False
            if InFlight and CellAlive and not timer.q:
                SendRequest = True
            elif CycleEdge and Ready:
                ReqId, NextReqId, InFlight, SendRequest = NextReqId, NextReqId + 1, True, True
            if SendRequest:
                plc["cycle_req_id"] = ReqId
                plc["cycle_request"] = 1
                CycleStep = 10
        elif CycleStep == 10:
            if Flags_done and cell["ack"] == ReqId:
                result_read, InFlight = True, False
                plc["cycle_request"] = 0
                CycleStep = 20
        elif CycleStep == 20:
            if not Flags_done:
                CycleStep = 0
        CycleBusy = CycleStep != 0
        if timer(CycleBusy, now):
            if timed_out_at is None:
                timed_out_at = now
            plc["cycle_request"] = 0
            CycleStep = 0
        # (end of scan: the FC16 write carries plc[...] as it is now)
    assert timed_out_at is not None
    assert requests_seen_after_timeout > 0, (
        f"after the timeout at {timed_out_at:.2f} s the block wrote cycle_request = 0 in every scan up to {now:.1f} s: "
        "it never asked for the same id again")
    assert result_read, "the result of the id in flight was never read (InFlight stays set: no new request either)"
