"""The line PLC's Modbus TCP interface: register map, codec, handshakes and server.

The rest of the cell is reached only through ``CellFacade`` (plc/facade.py).
"""

from cellctl.plc import facade
from cellctl.plc.facade import *  # noqa: F403 - the facade's values are the package's vocabulary
from cellctl.plc.server import PlcServer

__all__ = [*facade.__all__, "PlcServer"]
