"""The line PLC's Modbus TCP interface."""

from __future__ import annotations

import ipaddress
from typing import Literal

from pydantic import Field, field_validator, model_validator

from cellctl.config.types import Finite, ListenHost, StrictModel


class PlcConfig(StrictModel):
    """Modbus TCP server settings (register map: docs/plc_register_map.md)."""

    enabled: bool = True
    host: ListenHost = "127.0.0.1"
    port: int = Field(5020, ge=0, le=65535)  # 0: any free port (tests); the server reports the one it got
    unit_id: int = Field(1, ge=0, le=255)  # 0: answer every unit id
    float_word_order: Literal["big", "little"] = "big"  # 32-bit values; "big": high word first (ABCD)
    heartbeat_timeout_s: Finite = Field(3.0, gt=0)
    # Raise the PLC_HEARTBEAT_LOST alarm (Hold, or Abort while the robot moves) when the PLC's
    # heartbeat stops. Keep it on for a line; the simulated cell runs without a PLC and logs only.
    heartbeat_alarm: bool = True  # plc_heartbeat unchanged this long: link lost
    cell_heartbeat_period_s: Finite = Field(0.5, gt=0)  # cell_heartbeat increments this often
    scan_period_s: Finite = Field(0.02, gt=0, le=1.0)  # PLC block read and status publish period
    facade_timeout_s: Finite = Field(5.0, gt=0)  # longest wait for one answer from the cell
    cycle_result_timeout_s: Finite = Field(900.0, gt=0)  # longest wait for an accepted cycle's result
    # robot_clear (cycle_flags bit 9): the flange at least this far (mm) in front of the car body's wall, along the
    # wall's normal. Commission it from the cell's layout (gripper length, car body contour, the cycle's end pose):
    # the default counts the simulated cell's end pose (389 mm) as clear, its shooting (342 mm) and install (120 mm) not.
    clear_distance_mm: Finite = Field(350.0, gt=0)
    # Modbus TCP has no authentication: only these client addresses or networks may connect ("10.1.2.3",
    # "10.1.2.0/24"); others are closed at once. Empty: any host that reaches the port (README, "Security").
    allowed_clients: tuple[str, ...] = ()
    # A Modbus TCP connection without a request this long is closed (a PLC polls every scan; one that lost power
    # or its cable, or an HMI that never closes its connections, would hold a file descriptor for good). Not set:
    # :attr:`idle_after_s`, 60 s or twice heartbeat_timeout_s, whichever is longer.
    idle_timeout_s: Finite | None = Field(None, gt=0, le=86400.0)

    @property
    def idle_after_s(self) -> float:
        """Seconds without a request after which a connection is closed: ``idle_timeout_s``, else its default."""
        return self.idle_timeout_s if self.idle_timeout_s is not None else max(60.0, 2.0 * self.heartbeat_timeout_s)

    @field_validator("allowed_clients")
    @classmethod
    def _networks(cls, value: tuple[str, ...]) -> tuple[str, ...]:
        for entry in value:
            try:
                ipaddress.ip_network(entry, strict=True)
            except ValueError as err:
                raise ValueError(f"plc.allowed_clients: {entry!r} is not an IP address or network ({err}); give e.g. "
                                 '"10.1.2.3" (the PLC) or "10.1.2.0/24" (its network, host bits zero)') from None
        return value

    def client_networks(self) -> tuple[ipaddress.IPv4Network | ipaddress.IPv6Network, ...]:
        """``allowed_clients`` as networks (an address is a network of one)."""
        return tuple(ipaddress.ip_network(entry) for entry in self.allowed_clients)

    def clients_note(self) -> str:
        """Who may command the cell over Modbus, in a line (``cellctl config check``)."""
        if self.allowed_clients:
            return "clients " + ", ".join(self.allowed_clients) + " only (plc.allowed_clients)"
        return ("any host that reaches the port may command the cell (Modbus has no authentication): list the "
                "PLC's address in plc.allowed_clients and firewall the port (README, Security)")

    @model_validator(mode="after")
    def _periods_fit(self) -> "PlcConfig":
        if self.heartbeat_timeout_s < 3 * self.scan_period_s:
            raise ValueError(
                f"plc.heartbeat_timeout_s = {self.heartbeat_timeout_s:g} s is shorter than three scans "
                f"(plc.scan_period_s = {self.scan_period_s:g} s): raise the timeout or shorten the scan")
        if self.cell_heartbeat_period_s < self.scan_period_s:
            raise ValueError(
                f"plc.cell_heartbeat_period_s = {self.cell_heartbeat_period_s:g} s is shorter than one scan "
                f"(plc.scan_period_s = {self.scan_period_s:g} s): the cell heartbeat changes once per "
                "scan at most; raise it")
        if self.idle_timeout_s is not None and self.idle_timeout_s <= self.heartbeat_timeout_s:
            raise ValueError(
                f"plc.idle_timeout_s = {self.idle_timeout_s:g} s is not longer than plc.heartbeat_timeout_s = "
                f"{self.heartbeat_timeout_s:g} s: the cell would close the connection of a PLC that changes its "
                "heartbeat just in time; raise it, or leave it out (60 s, or twice heartbeat_timeout_s if longer)")
        if self.cycle_result_timeout_s < self.facade_timeout_s:
            raise ValueError(
                f"plc.cycle_result_timeout_s = {self.cycle_result_timeout_s:g} s is shorter than "
                f"plc.facade_timeout_s = {self.facade_timeout_s:g} s: raise it")
        return self
