"""The line PLC's Modbus TCP interface: register map, codec, handshakes and server.

The rest of the cell is reached only through ``CellFacade`` (plc/facade.py).
"""

from cellctl.plc.facade import CellFacade, CellStatus, CommandReply, CycleAcceptance, CycleOutcome, PlcErrorCode
from cellctl.plc.server import PlcServer

__all__ = ["CellFacade", "CellStatus", "CommandReply", "CycleAcceptance", "CycleOutcome", "PlcErrorCode", "PlcServer"]
