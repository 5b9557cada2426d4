"""The node set is defined once: the server serves exactly it (browsed by an independent client by browse
path, as a PackML client finds nodes) and docs/opcua_nodeset.md is rendered from it."""

from __future__ import annotations

from pathlib import Path

import pytest
from asyncua import ua
from opcua_test_support import ns_of, opcua_client, running_service, secure_config

from cellctl.domain import PackMLState
from cellctl.opcua.nodeset import (
    CELLCTL_NS,
    METHODS,
    PACKML_NS,
    VARIABLES,
    folders,
    state_path,
)
from cellctl.opcua.nodeset_doc import render_markdown

REPO = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.timeout(120)


def test_the_committed_doc_is_the_generated_one() -> None:
    doc = REPO / "docs" / "opcua_nodeset.md"
    assert doc.read_text(encoding="utf-8") == render_markdown(), (
        "docs/opcua_nodeset.md is stale: run python -m cellctl.opcua.nodeset_doc -o docs/opcua_nodeset.md")


def test_state_numbers_follow_opc_30050() -> None:
    # Aborted is a state of the base machine; Stopped of the machine state machine in Cleared (19);
    # Execute of the execute machine in Running (18), as the PackML NodeSet numbers them.
    assert state_path(PackMLState.ABORTED) == (("Aborted", 9), ("", 0), ("", 0))
    assert state_path(PackMLState.STOPPED) == (("Cleared", 19), ("Stopped", 2), ("", 0))
    assert state_path(PackMLState.EXECUTE) == (("Cleared", 19), ("Running", 18), ("Execute", 6))
    assert state_path(PackMLState.HELD) == (("Cleared", 19), ("Running", 18), ("Held", 11))


async def test_every_defined_node_is_served_at_its_browse_path(tmp_path: Path) -> None:
    async with running_service(tmp_path, secure_config()) as service, opcua_client(service, tmp_path) as client:
        packml = await client.get_namespace_index(PACKML_NS)
        cellctl = await ns_of(client)
        assert cellctl == await client.get_namespace_index(CELLCTL_NS)
        ns_index = {"packml": packml, "cellctl": cellctl}
        cell = await client.nodes.objects.get_child([f"{packml}:PackMLObjects", f"{cellctl}:cell-1"])
        ns_of_path = {p: ns_index[n] for p, n in folders()} | {i.path: ns_index[i.ns] for i in (*VARIABLES, *METHODS)}
        for item in (*VARIABLES, *METHODS):
            parts = item.path.split("/")
            names = [f"{ns_of_path['/'.join(parts[: k + 1])]}:{part}" for k, part in enumerate(parts)]
            node = await cell.get_child(names)
            assert node.nodeid == ua.NodeId(f"cell-1.{item.path.replace('/', '.')}", cellctl), item.path
            cls = await node.read_node_class()
            assert cls == (ua.NodeClass.Method if item in METHODS else ua.NodeClass.Variable), item.path
            assert (await node.read_description()).Text, item.path
            if item in VARIABLES:  # nobody writes the address space: every value is read-only
                level = (await node.read_attribute(ua.AttributeIds.AccessLevel)).Value.Value
                assert not level & (1 << ua.AccessLevel.CurrentWrite), item.path
        # A state's Id is a node that exists, of StateType, with its number.
        cs = await cell.get_child([f"{packml}:BaseStateMachine", f"{packml}:CurrentState"])
        state_id = await (await cs.get_child(f"{packml}:Id")).read_value()
        assert (await client.get_node(state_id).read_browse_name()).Name == "Aborted"
        number = await client.get_node(state_id).get_child("0:StateNumber")
        assert await number.read_value() == 9
