"""Which side a gap in the robot's position feedback was on (alarm 1402): the controller's or the cell PC's.

The stream's own statistics tell them apart: a gap in the controller's stamps (``header.tm``, the
controller's clock) is one the controller sent nothing in, or whose datagrams were lost on the way
(the sequence numbers show those); samples stamped on time but received late are a PC that read late
(a loaded cell PC), not the link. Robot drivers without such statistics are told as before.
"""

from __future__ import annotations

import math
from typing import Any

LINK_HINT = "check the EGM link (UdpUc device, network, firewall)"


def stream_stats(stream: object) -> Any | None:
    """The stream's statistics (the ABB driver's ``stream_stats``: received, lost, max_interval_s, delay_max_s), or None."""
    try:
        stats = getattr(stream, "stream_stats", None)
    except Exception:  # a driver whose stats cannot be had now: told without them
        return None
    return stats if stats is not None and hasattr(stats, "max_interval_s") and hasattr(stats, "delay_max_s") else None


def stream_figures(stats: Any | None) -> dict[str, Any]:
    """The stream's statistics for the failing step's record (s -> ms); {} without statistics."""
    if stats is None:
        return {}

    def ms(x: float) -> float | None:
        return None if not math.isfinite(x) else round(1e3 * float(x), 3)

    return {"feedback_stream": {
        "received": int(stats.received), "lost": int(stats.lost), "gap_events": int(getattr(stats, "gap_events", 0)),
        "max_interval_ms": ms(stats.max_interval_s), "max_receipt_delay_ms": ms(stats.delay_max_s),
        "stamp": str(getattr(stats, "stamp", "")),
    }}  # fmt: skip


def gap_side(stats: Any | None, gap_s: float, *, came_after: int) -> str:
    """Which side a feedback gap of ``gap_s`` (s) was on, as the stream's statistics tell it (``came_after``: samples
    that arrived after the gap was found, before the stream stopped); the link hint without statistics."""
    if stats is None:
        return LINK_HINT
    interval, delay, lost = float(stats.max_interval_s), float(stats.delay_max_s), int(stats.lost)
    said = f"longest gap in the controller's stamps {interval:.3f} s, latest receipt on the PC {delay:.3f} s after the stamp"
    if came_after <= 0:  # the stream just ended: nothing after the gap tells whether it was sent
        return f"nothing arrived after it until the stream was stopped: the controller stopped sending or the link dropped; {LINK_HINT}"
    if getattr(stats, "stamp", "tm") == "receive":  # no controller stamps: the two sides cannot be told apart
        return f"the stream has no controller stamps to tell the sides apart; {LINK_HINT}"
    interval = interval if math.isfinite(interval) else 0.0
    delay = delay if math.isfinite(delay) else 0.0
    if max(interval, delay) < 0.5 * gap_s:
        return f"neither side shows a gap this long ({said}): the cell PC's supervision ran late (a loaded cell PC)"
    if interval >= delay:
        if lost:
            return (f"the controller's stamps have a gap of {interval:.3f} s and {lost} datagram(s) are missing by sequence "
                    f"number: lost between the controller and the PC ({said}); {LINK_HINT}")  # fmt: skip
        return (f"the controller sent nothing for {interval:.3f} s (a gap in its own stamps, no datagram missing): the "
                f"robot controller paused its stream (its load, the EGM task), not the network ({said})")  # fmt: skip
    return (f"the controller sent on time but the PC received a sample {delay:.3f} s late: a loaded cell PC, not the "
            f"controller or the network ({said})")  # fmt: skip
