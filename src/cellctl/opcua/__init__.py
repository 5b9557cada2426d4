"""The plant's OPC UA interface: the PackML model of OPC 30050, per-part results, alarms as events.

:mod:`~cellctl.opcua.nodeset` defines the address space once; :mod:`~cellctl.opcua.server` serves it
over the cell as :class:`~cellctl.opcua.port.OpcUaCell` describes it.
"""
