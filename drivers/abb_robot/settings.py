"""The ABB driver's settings: how to reach and drive the controller, ``[devices.robot]`` with ``kind = "abb"``."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from abb_robot import protocol as P


@dataclass(frozen=True)
class AbbRobotSettings:
    """How to reach and drive the controller; mirrors ``[devices.robot]`` with ``kind = "abb"``.

    Attributes:
        host: controller address (its WAN/LAN port, not the service port).
        rapid_port: TCP port of the RAPID server module.
        egm_port: UDP port this PC binds for EGM (the controller's UDPUC remote port);
            None disables fine correction and the position stream.
        egm_bind_host: local address the EGM port is bound on.
        connect_timeout_s: longest wait for the TCP connection itself.
        request_timeout_s: how long a request the controller answers at once (handshake, settings, POS, GETC,
            a motion's ACK, ...) may wait for its answer; a motion's DONE has the move's own deadline.
        heartbeat_period_s: PING after this much quiet on the link.
        heartbeat_timeout_s: drop the link when a PING is not answered within this.
        reconnect_delay_s, reconnect_max_delay_s: background reconnection back-off.
        keepalive_idle_s, keepalive_interval_s, keepalive_count: TCP keepalive.
        tool, wobj: tooldata and wobjdata names on the controller (tool0/wobj0: the flange in
            the base frame, which is what :class:`cellctl.ports.Robot` speaks).
        speed_mm_s, speed_deg_s: speed sent before any move asks for its own.
        zone_mm: zone of moves; 0 is a fine point (the Robot port's moves end at fine points).
        egm_receive_timeout_s: EGM silence after which a session counts as lost.
        egm_cond_time_s: how long the pose must stay converged before the controller ends EGM.
        egm_max_correction_mm, egm_max_correction_deg: larger corrections are refused (use move()).
        egm_max_rate_hz: upper bound of the EGM reply rate.
        egm_settle_cycles: converged cycles the standalone EGM peer waits for.
        egm_rt_priority: SCHED_FIFO priority for the EGM loop (None: normal scheduling).
        egm_isolation: "process" runs the EGM loop in a child process (no interpreter lock
            shared with the cell's code), "thread" in this process.
    """

    host: str
    rapid_port: int = 30100
    egm_port: int | None = 6511
    egm_bind_host: str = "0.0.0.0"
    connect_timeout_s: float = 3.0
    request_timeout_s: float = 2.0
    heartbeat_period_s: float = 1.0
    heartbeat_timeout_s: float = 2.0
    reconnect_delay_s: float = 0.5
    reconnect_max_delay_s: float = 5.0
    keepalive_idle_s: int = 10
    keepalive_interval_s: int = 3
    keepalive_count: int = 3
    tool: str = "tool0"
    wobj: str = "wobj0"
    speed_mm_s: float = 100.0
    speed_deg_s: float = 30.0
    zone_mm: float = 0.0
    egm_receive_timeout_s: float = 0.5
    egm_cond_time_s: float = 0.1
    egm_max_correction_mm: float = 20.0
    egm_max_correction_deg: float = 2.0
    egm_max_rate_hz: float = 250.0
    egm_settle_cycles: int = 5
    egm_rt_priority: int | None = None
    egm_isolation: Literal["process", "thread"] = "process"

    def __post_init__(self) -> None:
        if not self.host:
            raise ValueError("host must name the controller")
        if not (1 <= self.rapid_port <= 65535):
            raise ValueError(f"rapid_port must be 1..65535, got {self.rapid_port}")
        if self.egm_port is not None and not (0 <= self.egm_port <= 65535):
            raise ValueError(f"egm_port must be 0..65535 or None, got {self.egm_port}")
        for name in (
            "connect_timeout_s", "request_timeout_s", "heartbeat_period_s", "heartbeat_timeout_s",
            "reconnect_delay_s", "reconnect_max_delay_s", "speed_mm_s", "speed_deg_s",
            "egm_receive_timeout_s", "egm_max_correction_mm", "egm_max_correction_deg", "egm_max_rate_hz",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {value}")
        P.check_name(self.tool, "tool")
        P.check_name(self.wobj, "wobj")
        if not (0 <= self.zone_mm <= 2000):
            raise ValueError(f"zone_mm must be 0..2000 (0 = fine), got {self.zone_mm}")
        if self.egm_rt_priority is not None and not (1 <= self.egm_rt_priority <= 99):
            raise ValueError(f"egm_rt_priority must be 1..99 or None, got {self.egm_rt_priority}")
        if self.egm_settle_cycles < 1:
            raise ValueError(f"egm_settle_cycles must be >= 1, got {self.egm_settle_cycles}")
        if self.egm_isolation not in ("process", "thread"):
            raise ValueError(f"egm_isolation must be 'process' or 'thread', got {self.egm_isolation!r}")
        if not (0 < self.egm_cond_time_s <= 60):
            raise ValueError(f"egm_cond_time_s must be in (0, 60], got {self.egm_cond_time_s}")
