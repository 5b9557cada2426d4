"""The cell's alarms as OPC UA Alarms & Conditions: one AlarmConditionType object per alarm code,
an event on every change (raised, cleared, acknowledged), Acknowledge and ConditionRefresh.

Events are emitted from the Server object (HMIs subscribe there) with the cell as SourceNode. An
event is retained while its alarm is active or unacknowledged, so ConditionRefresh replays it.
Acknowledge checks the EventId against the condition's latest event (an older one answers
BadEventIdUnknown, as Part 9 asks), then acknowledges through the cell, which audits the caller.
"""

from __future__ import annotations

import logging
from collections.abc import Awaitable, Callable
from datetime import UTC

from asyncua import Server, ua
from asyncua.common.node import Node
from asyncua.server.event_generator import EventGenerator

from cellctl.domain import Alarm
from cellctl.opcua.nodeset import ALARM_SEVERITY

log = logging.getLogger(__name__)

Acknowledger = Callable[[str, str], Awaitable[Alarm]]
"""(alarm uid, comment) -> the acknowledged alarm; raises KeyError for an unknown uid."""


def condition_name(alarm: Alarm) -> str:
    return f"{int(alarm.code)} {alarm.code.name}"


class AlarmConditions:
    """Condition nodes made as alarms first occur; their events follow every change of the alarm."""

    def __init__(self, server: Server, folder: Node, source: Node, ns: int, cell_id: str, acknowledge: Acknowledger) -> None:
        self._server = server
        self._folder = folder
        self._source = source
        self._ns = ns
        self._cell_id = cell_id
        self._acknowledge = acknowledge
        self._conditions: dict[int, tuple[Node, EventGenerator]] = {}
        self._last: dict[ua.NodeId, tuple[tuple[str, bool, bool], bytes]] = {}  # condition -> ((uid, active, acked), EventId) of its last event

    async def install(self) -> None:
        """Answer the standard Acknowledge method (clients call it with the ConditionId as the object)."""
        self._server.link_method(self._server.get_node(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge), self._on_acknowledge)

    async def publish(self, alarm: Alarm) -> None:
        """An event for the alarm's current state (raised, cleared or acknowledged); none if its
        condition state has not changed since the last event (e.g. the cell only issued its reaction)."""
        node, gen = await self._condition(alarm)
        state = (alarm.uid, alarm.active, alarm.acknowledged)
        last = self._last.get(node.nodeid)
        if last is not None and last[0] == state:
            return
        ev = gen.event
        ev.NodeId = node.nodeid
        ev.SourceNode = self._source.nodeid
        ev.SourceName = self._cell_id
        ev.ConditionName = condition_name(alarm)
        ev.Severity = ALARM_SEVERITY.get(int(alarm.severity), 500)
        ev.Retain = alarm.active or not alarm.acknowledged
        ev.EnabledState = ua.LocalizedText("Enabled")
        setattr(ev, "EnabledState/Id", True)
        ev.ActiveState = ua.LocalizedText("Active" if alarm.active else "Inactive")
        setattr(ev, "ActiveState/Id", alarm.active)
        ev.AckedState = ua.LocalizedText("Acknowledged" if alarm.acknowledged else "Unacknowledged")
        setattr(ev, "AckedState/Id", alarm.acknowledged)
        changed = alarm.ack_at or alarm.cleared_at or alarm.raised_at
        when = changed if changed.tzinfo else changed.replace(tzinfo=UTC)
        await gen.trigger(time_attr=when, message=alarm.message)
        event_id = ev.EventId.Value if isinstance(ev.EventId, ua.Variant) else ev.EventId
        self._last[node.nodeid] = (state, bytes(event_id))

    async def _condition(self, alarm: Alarm) -> tuple[Node, EventGenerator]:
        code = int(alarm.code)
        known = self._conditions.get(code)
        if known is not None:
            return known
        name = condition_name(alarm).replace(" ", "_")
        node = await self._folder.add_object(
            ua.NodeId(f"{self._cell_id}.Alarms.{name}", self._ns), ua.QualifiedName(name, self._ns),
            objecttype=ua.ObjectIds.AlarmConditionType, instantiate_optional=False,
        )  # fmt: skip
        ack = await node.get_child("0:Acknowledge")
        self._server.link_method(ack, self._on_acknowledge)
        gen = await self._server.get_event_generator(ua.ObjectIds.AlarmConditionType, ua.ObjectIds.Server)
        self._conditions[code] = (node, gen)
        return node, gen

    async def _on_acknowledge(self, parent: ua.NodeId, *args: ua.Variant) -> ua.StatusCode | list[ua.Variant]:
        if len(args) < 2:
            return ua.StatusCode(ua.StatusCodes.BadArgumentsMissing)
        known = self._last.get(parent)
        if known is None:
            return ua.StatusCode(ua.StatusCodes.BadNodeIdUnknown)
        (uid, _active, acked), latest = known
        event_id = args[0].Value if isinstance(args[0], ua.Variant) else args[0]
        if not isinstance(event_id, bytes) or event_id != latest:
            return ua.StatusCode(ua.StatusCodes.BadEventIdUnknown)
        if acked:
            return ua.StatusCode(ua.StatusCodes.BadConditionBranchAlreadyAcked)
        comment = args[1].Value if isinstance(args[1], ua.Variant) else args[1]
        text = comment.Text if isinstance(comment, ua.LocalizedText) else str(comment or "")
        try:
            await self._acknowledge(uid, text)
        except KeyError:
            return ua.StatusCode(ua.StatusCodes.BadEventIdUnknown)
        return []  # the acknowledged alarm's own event follows from the cell's alarm feed
