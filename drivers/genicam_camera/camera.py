"""A GenICam camera through a GenTL producer (harvesters), behind :class:`cellctl.ports.Camera`.

harvesters is synchronous, so every call into it runs on one dedicated worker thread (GenTL
handles stay on the thread that made them, and calls are serialised); the coroutine waits for it
with the call's timeout, so a stuck producer ends in DeviceTimeout, never a hang.

A grab in software-trigger mode first returns any queued buffers to the producer, waits until the
frames of earlier triggers (a grab that timed out) have landed and drops them, then fires
``TriggerSoftware`` and waits for the frame it produced, so the image is one taken after the
call began. In free-run mode it returns the next frame after the queue was emptied.
A GenTL failure releases the camera and the producer; the next call opens both afresh.

harvesters and genicam are an optional extra (``pip install 'cellctl[camera]'``): they are
imported when the camera is opened, and a missing one is reported with that fix.
"""

from __future__ import annotations

import asyncio
import collections
import concurrent.futures
import logging
import math
import os
import time
from dataclasses import dataclass
from typing import Any, Callable, Literal, Mapping, TypeVar

from cellctl.ports import DeviceDisconnected, DeviceError, DeviceProtocolError, DeviceRejected, DeviceTimeout, Frame
from genicam_camera.pixels import MONO_BITS, to_mono8

_log = logging.getLogger(__name__)

TriggerMode = Literal["software", "free_run"]
_T = TypeVar("_T")
_DRAIN_POLL_S = 0.001  # harvesters treats a fetch timeout of 0 as "wait forever"
ENUMERATION_S = 3.0
"""Longest wait (s) for the GenTL producer to enumerate its cameras, once or twice at an open."""


class _NoFrame(Exception):
    """No buffer arrived before the deadline."""


@dataclass(frozen=True)
class CameraInfo:
    """What the transport layer says about the opened camera."""

    model: str
    vendor: str
    serial_number: str
    user_id: str


def _node(node_map: Any, name: str) -> Any | None:
    return getattr(node_map, name) if node_map.has_node(name) else None


class GenicamCamera:
    """A monochrome GenICam camera opened through the GenTL producer at ``cti_path``.

    Args:
        cti_path: the GenTL producer (.cti) file, where its vendor installed it.
        serial_number: picks the camera by its transport-layer serial number.
        user_id: picks the camera by its user-defined name (DeviceUserID).
        pixel_format: the unpacked Mono format to set; deeper ones are scaled to 8 bits.
        exposure_us: exposure time to set (None: leave the camera's).
        gain_db: gain to set (None: leave the camera's).
        trigger_mode: "software" (one trigger per grab) or "free_run".
        timeout_s: bound on opening the camera and writing its settings.
        frame_lost_after_s: how long after its software trigger (beyond the exposure) a frame may
            still land; an earlier trigger whose frame has not landed by then is taken as lost.
        expected_size_px: (width, height) the cell's lens is calibrated for; a camera whose Width/Height
            differ is refused when opened (None: not checked).
        name: the device's name in errors.
    """

    def __init__(
        self,
        *,
        cti_path: str,
        serial_number: str | None = None,
        user_id: str | None = None,
        pixel_format: str = "Mono8",
        exposure_us: float | None = None,
        gain_db: float | None = None,
        trigger_mode: TriggerMode = "software",
        timeout_s: float = 5.0,
        frame_lost_after_s: float = 1.0,
        expected_size_px: tuple[int, int] | None = None,
        name: str = "camera",
    ) -> None:
        if not cti_path:
            raise ValueError("cti_path must name the GenTL producer (.cti) file")
        if pixel_format not in MONO_BITS:
            raise ValueError(f"pixel_format must be one of {', '.join(MONO_BITS)}, got {pixel_format!r}")
        if trigger_mode not in ("software", "free_run"):
            raise ValueError(f"trigger_mode must be 'software' or 'free_run', got {trigger_mode!r}")
        for label, value in (("exposure_us", exposure_us), ("gain_db", gain_db)):
            if value is not None and not math.isfinite(value):
                raise ValueError(f"{label} must be a finite number or None, got {value!r}")
        if exposure_us is not None and exposure_us <= 0:
            raise ValueError(f"exposure_us must be positive, got {exposure_us!r}")
        if not (math.isfinite(timeout_s) and timeout_s > 0):
            raise ValueError(f"timeout_s must be a positive number of seconds, got {timeout_s!r}")
        if not (math.isfinite(frame_lost_after_s) and frame_lost_after_s > 0):
            raise ValueError(f"frame_lost_after_s must be a positive number of seconds, got {frame_lost_after_s!r}")
        self.cti_path = cti_path
        self.serial_number = serial_number
        self.user_id = user_id
        self.pixel_format = pixel_format
        self.exposure_us = exposure_us
        self.gain_db = gain_db
        self.trigger_mode: TriggerMode = trigger_mode
        self.timeout_s = float(timeout_s)
        self.frame_lost_after_s = float(frame_lost_after_s)
        self.expected_size_px = None if expected_size_px is None else (int(expected_size_px[0]), int(expected_size_px[1]))
        self.name = name
        self.info: CameraInfo | None = None
        self._executor = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="genicam")
        self._harvester: Any = None
        self._acquirer: Any = None
        self._exposure_in_effect: float | None = None
        self._gain_in_effect: float | None = None
        self._frames = 0
        self._in_flight: collections.deque[float] = collections.deque()  # monotonic times of triggers not yet answered
        self._closed = False

    @classmethod
    def from_config(
        cls, config: Mapping[str, Any], *, expected_size_px: tuple[int, int] | None = None, name: str = "camera"
    ) -> "GenicamCamera":
        """Build from a ``[devices.camera]`` mapping (``kind = "genicam"``, e.g. ``model_dump()``)."""
        cfg = dict(config)
        cfg.pop("kind", None)
        return cls(**cfg, expected_size_px=expected_size_px, name=name)

    def identity(self) -> dict[str, str]:
        """What this camera is (:class:`cellctl.ports.Identified`): vendor, model, serial number and
        user id as the transport layer reported them when the camera was opened ("" before), and
        the GenTL producer it was opened through."""
        info = self.info
        return {
            "vendor": "" if info is None else info.vendor,
            "model": "" if info is None else info.model,
            "serial_number": "" if info is None else info.serial_number,
            "user_id": "" if info is None else info.user_id,
            "cti_path": self.cti_path,
        }

    # ------------------------------------------------------------------------------------------
    # Camera

    async def open(self, *, timeout_s: float | None = None) -> CameraInfo:
        """Open and configure the camera now (otherwise the first grab does)."""
        limit = self.timeout_s if timeout_s is None else min(timeout_s, self.timeout_s)
        await self._on_worker(self._open_blocking, limit, "opening the camera")
        assert self.info is not None
        return self.info

    async def grab(self, *, timeout_s: float) -> Frame:
        """Trigger (in software-trigger mode) and return one new frame."""
        self._check_timeout(timeout_s)
        deadline = time.monotonic() + timeout_s
        if self._acquirer is None:
            await self.open(timeout_s=timeout_s)
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise DeviceTimeout(self.name, f"opening the camera used up the grab's {timeout_s:g} s")
        return await self._on_worker(lambda: self._grab_blocking(deadline), remaining, "grabbing a frame")

    async def ping(self, *, timeout_s: float) -> float:
        """Read a node of the camera as a round trip; returns its duration in seconds."""
        self._check_timeout(timeout_s)
        start = time.monotonic()
        if self._acquirer is None:
            await self.open(timeout_s=timeout_s)
        else:
            await self._on_worker(self._ping_blocking, max(timeout_s - (time.monotonic() - start), 1e-3), "ping")
        return time.monotonic() - start

    async def close(self) -> None:
        """Stop acquisition and release the camera and the producer. Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        loop = asyncio.get_running_loop()
        try:
            await asyncio.wait_for(loop.run_in_executor(self._executor, self._release_blocking), self.timeout_s)
        except (TimeoutError, RuntimeError) as exc:
            _log.warning("%s: releasing the camera did not finish: %r", self.name, exc)
        finally:
            self._executor.shutdown(wait=False, cancel_futures=True)

    # ------------------------------------------------------------------------------------------

    def _check_timeout(self, timeout_s: float) -> None:
        if not (isinstance(timeout_s, (int, float)) and math.isfinite(timeout_s) and timeout_s > 0):
            raise ValueError(f"timeout_s must be a positive number of seconds, got {timeout_s!r}")

    async def _on_worker(self, fn: Callable[[], _T], timeout_s: float, what: str) -> _T:
        if self._closed:
            raise DeviceDisconnected(self.name, "closed")
        loop = asyncio.get_running_loop()
        try:
            return await asyncio.wait_for(loop.run_in_executor(self._executor, fn), timeout_s)
        except TimeoutError:
            raise DeviceTimeout(self.name, f"{what} took longer than {timeout_s:.3g} s") from None
        except _NoFrame:
            raise DeviceTimeout(self.name, f"no frame within the grab's timeout ({what})") from None
        except DeviceError:
            raise
        except Exception as exc:  # a GenTL/GenApi failure: the link to the camera is not usable
            self._executor.submit(self._release_blocking)  # the producer too: a second Harvester finds no camera
            raise DeviceDisconnected(
                self.name, f"{what} failed: {type(exc).__name__}: {exc}; the next call reopens the camera"
            ) from exc

    # --- on the worker thread -----------------------------------------------------------------

    def _open_blocking(self) -> None:
        if self._acquirer is not None:
            return
        self._release_blocking()  # a producer left loaded by a failure keeps the camera from a new Harvester
        try:
            from harvesters.core import Harvester, ParameterKey, ParameterSet
        except ImportError as exc:
            raise DeviceDisconnected(
                self.name, f"harvesters is not installed ({exc}); install the camera extra: pip install 'cellctl[camera]'"
            ) from exc
        if not os.path.isfile(self.cti_path):
            raise DeviceDisconnected(
                self.name, f"GenTL producer {self.cti_path} not found; set devices.camera.cti_path to the vendor's .cti file"
            )
        # The producer may take a while to find its cameras (GigE discovery, a loaded host): it is given up to
        # ENUMERATION_S per enumeration, and a second one when the first found no camera of ours.
        enumeration_ms = int(1000 * min(self.timeout_s, ENUMERATION_S))
        harvester = Harvester(config=ParameterSet({ParameterKey.TIMEOUT_PERIOD_ON_MODULE_ENUMERATION: enumeration_ms}))
        try:
            harvester.add_file(self.cti_path)
            harvester.update()
            if not any(self._is_ours(d) for d in harvester.device_info_list):
                harvester.update()
            device = self._select_device(harvester.device_info_list)
            acquirer = harvester.create(device)
            try:
                self._configure(acquirer.remote_device.node_map, device)
                acquirer.start()
            except BaseException:
                acquirer.destroy()
                raise
        except BaseException:
            harvester.reset()
            raise
        self._harvester, self._acquirer = harvester, acquirer
        self.info = CameraInfo(
            model=str(device.model), vendor=str(device.vendor),
            serial_number=str(device.serial_number), user_id=str(device.user_defined_name),
        )

    def _is_ours(self, d: Any) -> bool:
        """The device matches devices.camera's serial_number and user_id (those set)."""
        return (self.serial_number is None or str(d.serial_number) == self.serial_number) and (
            self.user_id is None or str(d.user_defined_name) == self.user_id)

    def _select_device(self, devices: list[Any]) -> Any:
        def describe(d: Any) -> str:
            return f"{d.model} (serial_number={d.serial_number!r}, user_id={d.user_defined_name!r})"

        matches = [d for d in devices if self._is_ours(d)]
        found = "; ".join(describe(d) for d in devices) or "none"
        if not matches:
            wanted = ", ".join(
                f"{k}={v!r}" for k, v in (("serial_number", self.serial_number), ("user_id", self.user_id)) if v is not None
            )
            raise DeviceDisconnected(self.name, f"no camera with {wanted or 'any id'} on {self.cti_path}; found: {found}")
        if len(matches) > 1:
            raise DeviceRejected(
                self.name,
                f"{len(matches)} cameras match; set devices.camera.serial_number (or user_id) to pick one of: {found}",
            )
        return matches[0]

    def _configure(self, nm: Any, device: Any) -> None:
        model = str(device.model)

        def refuse(what: str) -> DeviceRejected:
            return DeviceRejected(self.name, f"camera {model}: {what}")

        fmt = _node(nm, "PixelFormat")
        if fmt is not None and fmt.value != self.pixel_format:
            if self.pixel_format not in fmt.symbolics:
                raise refuse(f"no pixel format {self.pixel_format} (it offers {', '.join(fmt.symbolics)}); "
                             f"set devices.camera.pixel_format")
            fmt.value = self.pixel_format
        mode = _node(nm, "AcquisitionMode")
        if mode is not None and "Continuous" in mode.symbolics:
            mode.value = "Continuous"
        trigger = _node(nm, "TriggerMode")
        if self.trigger_mode == "software":
            if trigger is None or _node(nm, "TriggerSoftware") is None:
                raise refuse("no software trigger (TriggerMode/TriggerSoftware); set devices.camera.trigger_mode = 'free_run'")
            selector = _node(nm, "TriggerSelector")
            if selector is not None and "FrameStart" in selector.symbolics:
                selector.value = "FrameStart"
            trigger.value = "On"
            source = _node(nm, "TriggerSource")
            if source is not None:
                if "Software" not in source.symbolics:
                    raise refuse(f"TriggerSource has no 'Software' (it offers {', '.join(source.symbolics)})")
                source.value = "Software"
        elif trigger is not None:
            trigger.value = "Off"
        self._check_size(nm, refuse)
        self._exposure_in_effect = self._set_float(nm, ("ExposureTime", "ExposureTimeAbs"), "ExposureAuto",
                                                   self.exposure_us, "exposure_us", refuse)
        self._gain_in_effect = self._set_float(nm, ("Gain",), "GainAuto", self.gain_db, "gain_db", refuse)

    def _check_size(self, nm: Any, refuse: Callable[[str], DeviceRejected]) -> None:
        """Width and Height as the lens was calibrated for: a swapped camera, or one back with another ROI or binning."""
        if self.expected_size_px is None:
            return
        width, height = _node(nm, "Width"), _node(nm, "Height")
        if width is None or height is None:
            return  # a camera without the nodes: the cycle checks each frame's size instead
        got = (int(width.value), int(height.value))
        if got != self.expected_size_px:
            raise refuse(f"Width x Height is {got[0]} x {got[1]} px, not the {self.expected_size_px[0]} x "
                         f"{self.expected_size_px[1]} px of layout.camera (the lens's calibration): set the camera's "
                         "ROI, binning and decimation back, or pick this cell's camera (devices.camera.serial_number)")

    @staticmethod
    def _set_float(
        nm: Any, names: tuple[str, ...], auto: str, wanted: float | None, field: str,
        refuse: Callable[[str], DeviceRejected],
    ) -> float | None:
        node = next((n for n in (_node(nm, name) for name in names) if n is not None), None)
        if wanted is None:
            return float(node.value) if node is not None else None
        if node is None:
            raise refuse(f"no {names[0]} node; remove devices.camera.{field} to leave the camera's setting")
        auto_node = _node(nm, auto)
        if auto_node is not None and "Off" in auto_node.symbolics:
            auto_node.value = "Off"
        low, high = float(node.min), float(node.max)
        if not low <= wanted <= high:
            raise refuse(f"{field} = {wanted:g} is outside the camera's range [{low:g}, {high:g}]")
        node.value = wanted
        return float(node.value)

    def _grab_blocking(self, deadline: float) -> Frame:
        self._open_blocking()  # released by a failure after this call was queued: reopen now
        acquirer = self._acquirer
        self._return_queued(acquirer)
        if self.trigger_mode == "software":
            self._await_in_flight(acquirer, deadline)
            acquirer.remote_device.node_map.TriggerSoftware.execute()
            self._in_flight.append(time.monotonic())
        while (remaining := deadline - time.monotonic()) > 0:
            buffer = acquirer.try_fetch(timeout=max(remaining, _DRAIN_POLL_S))
            if buffer is not None:  # None early: an incomplete buffer, which harvesters queued again
                self._landed()
                return self._to_frame(buffer, time.monotonic())
        raise _NoFrame()

    def _landed(self) -> None:
        """A frame arrived: it answers the oldest trigger still in flight (if any)."""
        if self._in_flight:
            self._in_flight.popleft()

    def _return_queued(self, acquirer: Any) -> None:
        """Hand back to the producer what queued up before this call."""
        for _ in range(int(acquirer.num_buffers) + 2):
            stale = acquirer.try_fetch(timeout=_DRAIN_POLL_S)
            if stale is None:
                break
            stale.queue()
            self._landed()

    def _await_in_flight(self, acquirer: Any, deadline: float) -> None:
        """Wait for the frames of earlier triggers and drop them, so the next frame is this call's
        own; a trigger unanswered ``frame_lost_after_s`` plus the exposure after it is taken as lost."""
        lost_after_s = self.frame_lost_after_s + (self._exposure_in_effect or 0.0) * 1e-6
        while self._in_flight:
            now = time.monotonic()
            lost_at = self._in_flight[0] + lost_after_s
            if now >= lost_at:
                self._in_flight.popleft()
                _log.warning("%s: no frame %.3g s after a software trigger; taken as lost", self.name, lost_after_s)
                continue
            if now >= deadline:
                raise _NoFrame()
            stale = acquirer.try_fetch(timeout=max(min(lost_at, deadline) - now, _DRAIN_POLL_S))
            if stale is not None:
                stale.queue()
                self._landed()

    def _to_frame(self, buffer: Any, arrived: float) -> Frame:
        """Convert a fetched buffer to a Frame and hand the buffer back to the producer."""
        try:
            component = buffer.payload.components[0]
            delivered = str(component.data_format)
            try:
                image = to_mono8(component.data, int(component.width), int(component.height), delivered)
            except ValueError as exc:
                raise DeviceProtocolError(
                    self.name,
                    f"frame refused: the camera delivered {delivered} with PixelFormat set to {self.pixel_format}: {exc}",
                ) from exc
            try:
                device_ns: int | None = int(buffer.timestamp_ns)
            except Exception:  # the producer keeps no timestamp
                device_ns = None
            frame_id = getattr(buffer, "frame_id", None)
        finally:
            buffer.queue()
        self._frames += 1
        return Frame(
            image=image,
            timestamp_s=arrived,
            frame_id=int(frame_id) if frame_id is not None else self._frames,
            device_timestamp_ns=device_ns,
            exposure_us=self._exposure_in_effect,
            gain_db=self._gain_in_effect,
        )

    def _ping_blocking(self) -> None:
        self._open_blocking()  # released by a failure after this call was queued: reopen now
        nm = self._acquirer.remote_device.node_map
        node = _node(nm, "DeviceModelName") or _node(nm, "Width")
        if node is None:
            raise DeviceRejected(self.name, "camera has neither DeviceModelName nor Width to read")
        _ = node.value

    def _release_acquirer(self) -> None:
        acquirer, self._acquirer = self._acquirer, None
        self._in_flight.clear()
        if acquirer is not None:
            for step in (acquirer.stop, acquirer.destroy):
                try:
                    step()
                except Exception as exc:  # the device may already be gone
                    _log.warning("%s: %s failed while releasing: %r", self.name, step.__name__, exc)

    def _release_blocking(self) -> None:
        """Release the acquirer, then unload the producer (what a failure or close() does)."""
        self._release_acquirer()
        harvester, self._harvester = self._harvester, None
        if harvester is not None:
            try:
                harvester.reset()
            except Exception as exc:  # the producer may be in a bad state; a new Harvester loads it afresh
                _log.warning("%s: releasing the GenTL producer failed: %r", self.name, exc)
