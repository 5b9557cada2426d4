"""Builds the node set of :mod:`cellctl.opcua.nodeset` in an asyncua server and writes its values.

Values are written only when they change (a subscriber is notified on every write), with the
source timestamp of the cell's own change where it has one.
"""

from __future__ import annotations

from collections.abc import Callable
from datetime import UTC, datetime
from typing import Any

from asyncua import Server, ua
from asyncua.common.node import Node

from cellctl.opcua.nodeset import (
    CELLCTL_NS,
    METHODS,
    PACKML_NS,
    STATE_NAMES,
    VARIABLES,
    Arg,
    DataType,
    Var,
    folders,
    node_id_text,
)

NULL_TIME = datetime(1601, 1, 1, tzinfo=UTC)
"""OPC UA's null DateTime."""

_NULL: dict[str, Any] = {
    "Boolean": False, "Int32": 0, "UInt16": 0, "UInt32": 0, "Float": 0.0, "Double": 0.0, "String": "",
    "DateTime": NULL_TIME, "LocalizedText": ua.LocalizedText(""), "NodeId": ua.NodeId(),
}  # fmt: skip

Callback = Callable[..., Any]


def variant_type(t: DataType) -> ua.VariantType:
    return getattr(ua.VariantType, t)


def argument(a: Arg) -> ua.Argument:
    arg = ua.Argument()
    arg.Name = a.name
    arg.DataType = ua.NodeId(getattr(ua.ObjectIds, a.type))
    arg.ValueRank = 1 if a.array else -1
    arg.Description = ua.LocalizedText(a.description)
    return arg


class CellAddressSpace:
    """The cell's nodes in one server: ``nodes[path]`` for every object, variable and method path."""

    def __init__(self, server: Server, cell_id: str) -> None:
        self.server = server
        self.cell_id = cell_id
        self.nodes: dict[str, Node] = {}
        self._types: dict[str, ua.VariantType] = {}
        self._last: dict[str, tuple[Any, int]] = {}  # path -> (value, status code) last written
        self.ns: dict[str, int] = {}

    async def build(self, callbacks: dict[str, Callback]) -> Node:
        """Create every node; ``callbacks[path]`` answers the method at ``path``. Returns the cell object."""
        self.ns = {"packml": await self.server.register_namespace(PACKML_NS),
                   "cellctl": await self.server.register_namespace(CELLCTL_NS)}  # fmt: skip
        ns = self.ns["cellctl"]
        top = await self.server.nodes.objects.add_folder(ua.NodeId("PackMLObjects", ns), ua.QualifiedName("PackMLObjects", self.ns["packml"]))
        cell = await top.add_object(ua.NodeId(self.cell_id, ns), ua.QualifiedName(self.cell_id, ns))
        self.nodes[""] = cell
        for path, name_ns in folders():
            parent, name = self._parent(path)
            self.nodes[path] = await parent.add_object(self._nid(path), ua.QualifiedName(name, self.ns[name_ns]))
        for extra in ("States", "Alarms"):
            self.nodes[extra] = await cell.add_object(self._nid(extra), ua.QualifiedName(extra, ns))
        for number, name in sorted(STATE_NAMES.items()):
            state = await self.nodes["States"].add_object(self._nid(f"States/{name}"), ua.QualifiedName(name, ns),
                                                          objecttype=ua.ObjectIds.StateType)  # fmt: skip
            await (await state.get_child("0:StateNumber")).write_value(ua.Variant(number, ua.VariantType.UInt32))
        for v in VARIABLES:
            await self._add_variable(v)
        for m in METHODS:
            parent, name = self._parent(m.path)
            self.nodes[m.path] = await parent.add_method(
                self._nid(m.path), ua.QualifiedName(name, self.ns[m.ns]), callbacks[m.path],
                [argument(a) for a in m.inputs], [argument(a) for a in m.outputs],
            )  # fmt: skip
            await self.nodes[m.path].write_attribute(ua.AttributeIds.Description, ua.DataValue(ua.Variant(ua.LocalizedText(m.description))))
        return cell

    def state_node(self, number: int) -> ua.NodeId:
        """The node id of state ``number`` in the States folder (a CurrentState's Id), null for 0."""
        return self._nid(f"States/{STATE_NAMES[number]}") if number else ua.NodeId()

    async def write(self, path: str, value: Any, *, at: datetime | None = None, status: int = ua.StatusCodes.Good) -> bool:
        """Write ``path``'s value and status (a ``ua.StatusCodes`` code) if either changed; True if it did.

        A Bad status has no value: the server keeps null (OPC UA Part 4, 7.7.1) whatever ``value`` is.
        """
        if self._last.get(path, _MISSING) == (value, status):
            return False
        self._last[path] = (value, status)
        dv = ua.DataValue(ua.Variant(value, self._types[path]), StatusCode=ua.StatusCode(status),
                          SourceTimestamp=at or datetime.now(UTC), ServerTimestamp=datetime.now(UTC))  # fmt: skip
        await self.server.write_attribute_value(self.nodes[path].nodeid, dv)
        return True

    async def _add_variable(self, v: Var) -> None:
        parent, name = self._parent(v.path)
        vt = variant_type(v.type)
        init = [] if v.array else _NULL[v.type]
        qn = ua.QualifiedName(name, self.ns[v.ns])
        if v.property:
            node = await parent.add_property(self._nid(v.path), qn, ua.Variant(init, vt))
        else:
            node = await parent.add_variable(self._nid(v.path), qn, ua.Variant(init, vt), datatype=ua.NodeId(getattr(ua.ObjectIds, v.type)))
        if v.array:
            await node.write_attribute(ua.AttributeIds.ValueRank, ua.DataValue(ua.Variant(1, ua.VariantType.Int32)))
        await node.write_attribute(ua.AttributeIds.Description, ua.DataValue(ua.Variant(ua.LocalizedText(v.description))))
        self.nodes[v.path] = node
        self._types[v.path] = vt
        self._last[v.path] = (init, ua.StatusCodes.Good)

    def _parent(self, path: str) -> tuple[Node, str]:
        head, _, name = path.rpartition("/")
        return self.nodes[head], name

    def _nid(self, path: str) -> ua.NodeId:
        return ua.NodeId(node_id_text(self.cell_id, path), self.ns["cellctl"])


_MISSING = object()
