"""The cell's MQTT topic tree: ``{enterprise}/{site}/{area}/{line}/{cell}/cellctl/<topic>``.

:data:`TOPICS` is the one definition of what the cell publishes (docs/mqtt.md renders it);
:class:`CellTopics` turns it into the full topic names of one cell. The level names come from
``[mqtt.isa95]`` and are checked when the configuration loads (no ``+ # /``, no leading ``$``).
All topics are QoS 1. There are no command topics: commands stay on REST, Modbus and OPC UA.
"""

from __future__ import annotations

from dataclasses import dataclass

from cellctl.config.mqtt import Isa95Names, level_problem

APP_LEVEL = "cellctl"
"""The level under the cell that holds this service's topics (other applications of the cell may sit beside it)."""


@dataclass(frozen=True)
class TopicSpec:
    """One topic of the tree: its name under the cell's prefix, whether the broker retains it, what it carries."""

    name: str
    retained: bool
    kind: str  # the outbox kind (``result`` is dropped last) and the payload builder's name
    when: str
    what: str


TOPICS: tuple[TopicSpec, ...] = (
    TopicSpec("status", True, "status", "at every connection; the will at an unclean loss; at a clean stop",
              "online or not, the outbox's pending and dropped counts"),
    TopicSpec("state", True, "state", "every PackML state, unit mode or cycle step change; after each connection's backlog",
              "PackML state (PackTags integer and name), unit mode, cycle step"),
    TopicSpec("result", False, "result", "once per finished cycle (done, failed or interrupted), in cycle order",
              "the cycle's result: ok, error code, part and car ids, measured deviation (null when not measured), "
              "corrections (null when none was computed), times"),
    TopicSpec("result/last", True, "result_last", "with every result; after each connection's backlog", "the same payload as the last `result`"),
    TopicSpec("alarm/{code}", True, "alarm", "an alarm of that code raised, cleared or acknowledged; after each "
              "connection's backlog; emptied once it is inactive and acknowledged", "the alarm's state; an empty message clears the topic"),
    TopicSpec("alarm/events", False, "alarm_event", "every raise, clear and acknowledgement",
              "the alarm's state and what happened (`event`: `raised`, `cleared`, `acknowledged`; one message per "
              "change, so an acknowledgement that clears a latched alarm gives `cleared`, then `acknowledged`)"),
    TopicSpec("calibration", True, "calibration", "a new calibration set version (checked every 5 s); after each connection's backlog",
              "the calibration set's version in use"),
    TopicSpec("outbox/dropped", False, "dropped", "after a reconnection, when the bound dropped messages",
              "how many messages (and results) the outbox dropped unsent"),
)  # fmt: skip
"""Everything the cell publishes, in the order docs/mqtt.md lists it."""


class CellTopics:
    """The full topic names of one cell."""

    def __init__(self, names: Isa95Names) -> None:
        levels = names.levels()
        for level in levels:  # the config checks them; a hand-made Isa95Names.model_construct does not
            why = level_problem(level)
            if why is not None:
                raise ValueError(f"ISA-95 topic level {level!r} {why}")
        self.prefix = "/".join((*levels, APP_LEVEL))
        self.status = self.topic("status")
        self.state = self.topic("state")
        self.result = self.topic("result")
        self.result_last = self.topic("result/last")
        self.alarm_events = self.topic("alarm/events")
        self.calibration = self.topic("calibration")
        self.dropped = self.topic("outbox/dropped")
        self.everything = f"{self.prefix}/#"  # the subscription that takes the whole tree of this cell

    def topic(self, name: str) -> str:
        """``prefix/name`` for a name of :data:`TOPICS` (with ``{code}`` filled in)."""
        return f"{self.prefix}/{name}"

    def alarm(self, code: int) -> str:
        return self.topic(f"alarm/{int(code)}")

    def is_alarm(self, topic: str) -> bool:
        """``topic`` is one of this cell's retained ``alarm/{code}`` topics."""
        rest = topic.removeprefix(self.prefix + "/alarm/")
        return rest != topic and rest.isdigit()
