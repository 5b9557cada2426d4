"""The device watchdog: pings every device through its port, keeps link state and heartbeat age,
raises an alarm when a device is lost and clears it when the device answers again.

Each device has its own loop: every ``period_s`` it calls ``ping(timeout_s=...)`` (all ports have
it). A ping that raises or does not return within ``timeout_s`` (plus a small grace for the
driver's own timeout to fire first) is a miss, except one the device could not take because another
call held its link throughout (``DeviceBusy``, e.g. the laser's storage read-out, which has its own
timeout): that is neither an answer nor a miss. ``miss_threshold`` consecutive misses make the
link LOST and raise the device's alarm (robot -> Abort, laser/camera -> Hold, per
:data:`cellctl.cell.alarms.REACTIONS`); the first answer after that makes it UP again and clears
the alarm. A first miss raises a warning (DEVICE_SLOW) that clears on the next answer.
"""

from __future__ import annotations

import asyncio
import enum
import logging
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import Protocol, runtime_checkable

from cellctl.cell.alarms import AlarmManager
from cellctl.cell.cancel import cancel_first, cancel_until_done
from cellctl.domain import AlarmCode
from cellctl.ports import Camera, DeviceBusy, DisplacementSensor, Robot

_log = logging.getLogger(__name__)

TIMEOUT_GRACE_S = 0.25
"""How much longer than ``timeout_s`` the watchdog waits for a driver that ignores its timeout."""


@runtime_checkable
class Pingable(Protocol):
    async def ping(self, *, timeout_s: float) -> float: ...


class LinkState(enum.Enum):
    UNKNOWN = "unknown"  # not pinged yet
    UP = "up"
    DEGRADED = "degraded"  # missed, fewer than miss_threshold times in a row
    LOST = "lost"


@dataclass(frozen=True)
class WatchdogSettings:
    """How one device is supervised."""

    period_s: float = 1.0
    timeout_s: float = 0.5
    miss_threshold: int = 3

    def __post_init__(self) -> None:
        if not (self.period_s > 0):
            raise ValueError(f"watchdog period_s must be > 0, got {self.period_s}")
        if not (0 < self.timeout_s <= self.period_s):
            raise ValueError(
                f"watchdog timeout_s must be in (0, period_s = {self.period_s}], got {self.timeout_s}: "
                "a ping must end before the next one is due"
            )
        if self.miss_threshold < 1:
            raise ValueError(f"watchdog miss_threshold must be >= 1, got {self.miss_threshold}")


@dataclass(frozen=True)
class DeviceHealth:
    """What the dashboard shows per device.

    ``heartbeat_age_s`` is the time since the last answer (None if it never answered), measured
    when :meth:`DeviceWatchdog.health` is called.
    """

    name: str
    alarm_code: AlarmCode
    link: LinkState
    consecutive_misses: int
    heartbeat_age_s: float | None
    last_round_trip_s: float | None
    last_error: str | None
    pings: int
    misses: int
    settings: WatchdogSettings


def default_alarm_code(device: object) -> AlarmCode:
    """The lost-link alarm for a device, from the port it implements."""
    if isinstance(device, Robot):
        return AlarmCode.ROBOT_LOST
    if isinstance(device, Camera):
        return AlarmCode.CAMERA_LOST
    if isinstance(device, DisplacementSensor):
        return AlarmCode.LASER_LOST
    raise TypeError(
        f"{type(device).__name__} implements none of the Robot, Camera, DisplacementSensor ports: "
        "pass alarm_code= explicitly"
    )


@dataclass
class _Supervised:
    device: Pingable
    health: DeviceHealth
    last_ok_at: float | None = None
    task: asyncio.Task[None] | None = None


class DeviceWatchdog:
    """Supervises devices; one asyncio task per device while running.

    Args:
        alarms: where lost devices are raised and cleared.
        defaults: settings for devices added without their own.
        clock: monotonic clock (seconds).
    """

    def __init__(
        self,
        alarms: AlarmManager,
        *,
        defaults: WatchdogSettings = WatchdogSettings(),
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._alarms = alarms
        self._defaults = defaults
        self._clock = clock
        self._devices: dict[str, _Supervised] = {}
        self._running = False

    def add(
        self,
        name: str,
        device: Pingable,
        *,
        settings: WatchdogSettings | None = None,
        alarm_code: AlarmCode | None = None,
    ) -> None:
        """Supervise ``device`` under ``name`` (the alarm's source, e.g. ``laser``)."""
        if not name:
            raise ValueError("device name must not be empty")
        if name in self._devices:
            raise ValueError(f"device {name!r} is already supervised")
        if not isinstance(device, Pingable):
            raise TypeError(f"device {name!r} ({type(device).__name__}) has no ping(timeout_s=...) method")
        code = default_alarm_code(device) if alarm_code is None else AlarmCode(alarm_code)
        s = settings or self._defaults
        sup = _Supervised(device, DeviceHealth(name, code, LinkState.UNKNOWN, 0, None, None, None, 0, 0, s))
        self._devices[name] = sup
        if self._running:
            sup.task = asyncio.get_running_loop().create_task(self._loop(sup), name=f"watchdog:{name}")

    def health(self) -> dict[str, DeviceHealth]:
        now = self._clock()
        return {
            name: replace(sup.health, heartbeat_age_s=None if sup.last_ok_at is None else now - sup.last_ok_at)
            for name, sup in self._devices.items()
        }

    async def check_once(self) -> dict[str, DeviceHealth]:
        """Ping every device once, concurrently (also what each loop does per period)."""
        await asyncio.gather(*(self._check(sup) for sup in self._devices.values()))
        return self.health()

    async def start(self) -> None:
        if self._running:
            return
        self._running = True
        loop = asyncio.get_running_loop()
        for name, sup in self._devices.items():
            sup.task = loop.create_task(self._loop(sup), name=f"watchdog:{name}")

    async def stop(self) -> None:
        self._running = False
        # A driver's ping may swallow the cancel (its own wait_for, Python 3.11); the loop then ends at its next turn.
        await cancel_until_done([sup.task for sup in self._devices.values() if sup.task is not None])
        for sup in self._devices.values():
            sup.task = None

    async def __aenter__(self) -> DeviceWatchdog:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    # -- internals ----------------------------------------------------------------------------

    async def _loop(self, sup: _Supervised) -> None:
        period = sup.health.settings.period_s
        next_due = self._clock()
        while self._running:
            try:
                await self._check(sup)
            except asyncio.CancelledError:
                raise
            except Exception:  # the supervisor itself must survive anything a driver does
                _log.exception("watchdog check of %s failed", sup.health.name)
            next_due += period
            delay = next_due - self._clock()
            if delay < 0:  # overran (slow alarm handling): skip the missed slots, do not burst
                next_due = self._clock()
                delay = 0.0
            await asyncio.sleep(delay)

    async def _check(self, sup: _Supervised) -> None:
        s = sup.health.settings
        name = sup.health.name
        error: str | None = None
        rtt: float | None = None
        try:
            async with asyncio.timeout(s.timeout_s + TIMEOUT_GRACE_S):  # in this task: nothing left behind at a cancel
                rtt = float(await sup.device.ping(timeout_s=s.timeout_s))
        except Exception as exc:  # a cancel (not an Exception) goes up as it is
            cancel_first(exc)  # the stop's cancel, ended by the driver with its own error: no miss, no alarm
            if isinstance(exc, DeviceBusy):  # another call held the link throughout (it has its own timeout): no miss
                sup.health = replace(sup.health, pings=sup.health.pings + 1)
                return
            error = f"no answer within {s.timeout_s:g} s" if isinstance(exc, TimeoutError) else f"{type(exc).__name__}: {exc}"
        h = sup.health
        if error is None:
            sup.last_ok_at = self._clock()
            was = h.link
            sup.health = replace(h, link=LinkState.UP, consecutive_misses=0, last_round_trip_s=rtt,
                                 last_error=None, pings=h.pings + 1)  # fmt: skip
            self._alarms.clear(AlarmCode.DEVICE_SLOW, source=name)
            if was == LinkState.LOST:
                _log.info("%s is back", name)
                self._alarms.clear(h.alarm_code, source=name)
            return
        misses = h.consecutive_misses + 1
        lost = misses >= s.miss_threshold
        sup.health = replace(h, link=LinkState.LOST if lost else LinkState.DEGRADED, consecutive_misses=misses,
                             last_error=error, pings=h.pings + 1, misses=h.misses + 1)  # fmt: skip
        if lost and h.link != LinkState.LOST:
            _log.warning("%s lost after %d missed pings: %s", name, misses, error)
            self._alarms.clear(AlarmCode.DEVICE_SLOW, source=name)  # superseded by the lost alarm
            await self._alarms.raise_alarm(
                h.alarm_code, source=name, detail=f"{misses} pings missed in a row, last: {error}"
            )
        elif not lost and misses == 1:
            await self._alarms.raise_alarm(AlarmCode.DEVICE_SLOW, source=name, detail=error)


def watchdog_from_devices(
    alarms: AlarmManager,
    devices: Mapping[str, Pingable],
    *,
    settings: WatchdogSettings = WatchdogSettings(),
) -> DeviceWatchdog:
    """A watchdog over ``devices`` (name -> device), each with ``settings`` and its port's alarm."""
    wd = DeviceWatchdog(alarms, defaults=settings)
    for name, dev in devices.items():
        wd.add(name, dev)
    return wd
