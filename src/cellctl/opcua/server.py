"""The plant's OPC UA server: the node set of :mod:`cellctl.opcua.nodeset` over the cell, its methods,
its alarms as events, and the security a plant expects (started by ``cellctl serve`` like the Modbus server).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections import deque
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from asyncua import Server, ua
from asyncua.crypto.truststore import TrustStore
from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions

from cellctl.config.opcua import OpcUaConfig
from cellctl.domain import (
    DEVIATION_KEYS,
    Alarm,
    CycleStep,
    PackMLCommand,
    PackMLState,
    UnitMode,
)
from cellctl.listen import listen_problem
from cellctl.opcua.address_space import NULL_TIME, CellAddressSpace
from cellctl.opcua.alarms import AlarmConditions
from cellctl.opcua.channel_guard import NoneDiscoveryOnlyServer
from cellctl.opcua.nodeset import METHODS, STATE_MACHINES, UNIT_MODES, state_path
from cellctl.opcua.port import OpcUaCell, Refused
from cellctl.opcua.publishing import Publishing
from cellctl.opcua.security import (
    CellRuleset,
    CellUserManager,
    caller,
    certificate_uri,
    ensure_certificate,
    trusted_clients_problem,
)

log = logging.getLogger(__name__)

_POLICY = {
    "Basic256Sha256_SignAndEncrypt": ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt,
    "Basic256Sha256_Sign": ua.SecurityPolicyType.Basic256Sha256_Sign,
    "None": ua.SecurityPolicyType.NoSecurity,
}
SPEED_WINDOW = 10
"""Finished cycles whose mean time gives the machine speed."""


class OpcUaStartError(RuntimeError):
    """The OPC UA server cannot start with this configuration; the message names the field and the fix."""


class OpcUaPortInUse(OpcUaStartError):
    """Its port is held by another program: unlike the other start errors, this one can clear by itself."""


def _six(measured: dict[str, Any]) -> list[float]:
    """The measured deviation as [dx, dy, dz mm, drx, dry, drz deg]; empty when the cycle measured none."""
    return [float(measured[k]) for k in DEVIATION_KEYS] if measured else []


def _text(v: Any) -> str:
    """A string argument as text; a null one (Variant of type Null) is empty, i.e. not given."""
    value = v.Value if isinstance(v, ua.Variant) else v
    return "" if value is None else str(value)


class CellOpcUaServer:
    """Start with :meth:`start`, stop with :meth:`stop`; ``endpoint`` is where clients connect."""

    def __init__(self, cfg: OpcUaConfig, cell: OpcUaCell, *, root: Path) -> None:
        self._cfg = cfg
        self._cell = cell
        self._root = root
        self._server: Server | None = None
        self._space: CellAddressSpace | None = None
        self._alarms: AlarmConditions | None = None
        self._publishing: Publishing | None = None
        self._task: asyncio.Task[None] | None = None
        self._processed = 0
        self._defective = 0
        self._times: deque[float] = deque(maxlen=SPEED_WINDOW)
        self._shown: tuple[PackMLState, UnitMode, CycleStep] | None = None
        self.port = cfg.port
        self.application_uri = cfg.application_uri.format(cell_id=cell.cell_id)

    @property
    def endpoint(self) -> str:
        return f"opc.tcp://{self._cfg.host}:{self.port}{self._cfg.path}"

    def _path(self, p: Path) -> Path:
        return p if p.is_absolute() else self._root / p

    async def start(self) -> None:
        cfg = self._cfg
        try:
            users = CellUserManager.from_config(cfg, self._root)
        except ValueError as err:
            raise OpcUaStartError(str(err)) from None
        cert, key = self._path(cfg.certificate), self._path(cfg.private_key)
        if await asyncio.to_thread(ensure_certificate, cert, key, self.application_uri):
            log.warning("OPC UA: created the server certificate %s (and its key %s); give it to the plant's clients "
                        "to trust", cert, key)  # fmt: skip
        uri = await asyncio.to_thread(certificate_uri, cert)
        if uri != self.application_uri:
            raise OpcUaStartError(
                f"opcua.certificate {cert} is issued to '{uri}' but opcua.application_uri is '{self.application_uri}': "
                "delete the certificate and key to have new ones made, or set application_uri to the certificate's")
        server_class = Server if "None" in cfg.security_policies else NoneDiscoveryOnlyServer
        server = self._server = server_class(user_manager=users)  # type: ignore[arg-type]
        users.watch(server.iserver)  # tells a certificate user's token from an anonymous one's channel certificate
        server.iserver.bind_condition_methods = True  # ConditionRefresh; must precede init()
        await server.init()
        self._publishing = Publishing(server)  # a batch of writes reaches a subscriber in one notification
        server.set_endpoint(self.endpoint)
        server.set_server_name(f"cellctl {self._cell.cell_id}")
        await server.set_application_uri(self.application_uri)
        ruleset = CellRuleset()
        server.set_security_policy([_POLICY[p] for p in cfg.security_policies], permission_ruleset=ruleset)
        tokens: list[type] = [ua.UserNameIdentityToken, ua.X509IdentityToken]
        if cfg.allow_anonymous:
            tokens.append(ua.AnonymousIdentityToken)
        server.set_identity_tokens(tokens)
        await server.load_certificate(str(cert))
        await server.load_private_key(str(key))
        if cfg.trusted_clients is not None:
            folder = self._path(cfg.trusted_clients)
            if (problem := trusted_clients_problem(folder)) is not None:
                raise OpcUaStartError(problem)
            store = TrustStore([folder], [])
            await store.load()
            options = CertificateValidatorOptions.TRUSTED_VALIDATION | CertificateValidatorOptions.PEER_CLIENT
            server.set_certificate_validator(CertificateValidator(options, store))  # type: ignore[arg-type]
        space = CellAddressSpace(server, self._cell.cell_id)
        cell_node = await space.build(self._callbacks())
        ruleset.allow_viewers(*(space.nodes[m.path].nodeid for m in METHODS if m.read_only))
        self._alarms = AlarmConditions(server, space.nodes["Alarms"], cell_node, space.ns["cellctl"], self._cell.cell_id,
                                       self._acknowledge)  # fmt: skip
        await self._alarms.install()
        self._space = space
        await self._write_constants()
        try:
            await server.start()
        except OSError as err:  # the setting to change follows from the cause: a busy port, a foreign host, ...
            raise OpcUaPortInUse(f"the OPC UA server cannot listen on {cfg.host}:{cfg.port}: "
                                 f"{listen_problem('[opcua]', cfg.host, cfg.port, err)}") from None  # fmt: skip
        if server.bserver is not None:
            self.port = server.bserver.port
        if "None" in cfg.security_policies or cfg.allow_anonymous:
            log.warning("OPC UA on %s allows %s: for the simulated cell's demo only", self.endpoint,
                        " and ".join(w for w, on in (("security policy None", "None" in cfg.security_policies),
                                                     ("anonymous sessions", cfg.allow_anonymous)) if on))  # fmt: skip
        queue = self._cell.subscribe()
        await self._write_status()
        await self._write_last_result(await self._cell.last_result())
        for alarm in self._cell.alarms():
            await self._alarms.publish(alarm)
        self._task = asyncio.create_task(self._follow(queue))

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await self._task
        if self._server is not None:
            server, self._server = self._server, None
            try:
                await server.stop()
            except Exception:  # a server that never started fully has less to stop; the rest must still stop
                log.debug("OPC UA: stopping a partly started server", exc_info=True)

    # -- values ----------------------------------------------------------------------------------

    async def _follow(self, queue: asyncio.Queue[Any]) -> None:
        try:
            while True:
                ev = await queue.get()
                try:
                    await self._on_event(ev.kind, ev.data)
                except Exception:  # a bad event must not stop the updates; logged with its trace
                    log.exception("OPC UA: updating the nodes for %s failed", ev.kind)
        finally:
            self._cell.unsubscribe(queue)

    async def _on_event(self, kind: str, data: dict[str, Any]) -> None:
        if kind == "state":  # each transition in order, also an acting state the cell has already left
            await self._write_status(PackMLState[data["state"]], UnitMode[data["mode"]], CycleStep[data["step"].upper()])
        elif kind == "alarm":
            await self._write_status()
            alarm = self._cell.alarm(str(data.get("uid")))
            if alarm is not None and self._alarms is not None:
                await self._alarms.publish(alarm)
        elif kind == "cycle":
            if data.get("state") in ("done", "failed"):
                result = await self._cell.result_of_cycle(int(data["cycle_id"]))
                if result is not None and result["install_started"]:  # a glass used: done, or stopped after its install began
                    self._processed += 1
                    self._defective += 0 if result["ok"] else 1
                if result is not None and result["state"] == "done":
                    self._times.append(float(result["cycle_time_s"]))
                await self._write_last_result(result)
            await self._write_status()

    async def _write_constants(self) -> None:
        s = self._space
        assert s is not None
        await s.write("TagID", self._cell.cell_id)
        await s.write("PackMLVersion", "1.01")
        await s.write("Status/UnitSupportedModes", [int(m) for m in UNIT_MODES])
        await s.write("Status/EquipmentBlocked", False)

    async def _write_status(self, state: PackMLState | None = None, mode: UnitMode | None = None,
                            step: CycleStep | None = None) -> None:  # fmt: skip
        """The status nodes: the state, mode and step of a transition, else the last shown.

        Only the cell's transitions, in their order, move the state, mode and step shown (the snapshot
        only seeds them): a snapshot taken for another event may run ahead of transitions still queued,
        and writing it would show a client the state going back.
        """
        s = self._space
        if s is None:
            return
        snap = self._cell.snapshot()
        if state is not None and mode is not None and step is not None:
            self._shown = (state, mode, step)
        elif self._shown is None:
            self._shown = (snap.state, snap.mode, snap.step)
        state, mode, step = self._shown
        at = datetime.now(UTC)
        for machine, (name, number) in zip(STATE_MACHINES, state_path(state), strict=True):
            await s.write(f"{machine}/CurrentState", ua.LocalizedText(name), at=at)
            await s.write(f"{machine}/CurrentState/Id", s.state_node(number), at=at)
            await s.write(f"{machine}/CurrentState/Number", number, at=at)
        await s.write("Status/StateCurrent", int(state), at=at)
        await s.write("Status/UnitModeCurrent", int(mode), at=at)
        await s.write("Status/CycleStep", int(step), at=at)
        await s.write("Status/ReadyForCycle", snap.ready_for_cycle, at=at)
        await s.write("Status/EquipmentStarved", snap.ready_for_cycle and step is CycleStep.NONE, at=at)
        mean = sum(self._times) / len(self._times) if self._times else 0.0
        speed = 60.0 / mean if mean > 0 else 0.0
        await s.write("Status/MachSpeed", speed)
        await s.write("Status/CurMachSpeed", speed if state is PackMLState.EXECUTE else 0.0)
        await s.write("Admin/ProcessedCount", self._processed)
        await s.write("Admin/DefectiveCount", self._defective)
        await self._write_stop_reason(snap.stop_reason)

    async def _write_stop_reason(self, a: Alarm | None) -> None:
        s = self._space
        assert s is not None
        await s.write("Admin/StopReason/ID", 0 if a is None else int(a.code))
        await s.write("Admin/StopReason/Value", 0 if a is None else int(a.value))
        await s.write("Admin/StopReason/Message", "" if a is None else a.message)
        await s.write("Admin/StopReason/Category", 0 if a is None else int(a.category))
        await s.write("Admin/StopReason/DateTime", NULL_TIME if a is None else a.raised_at)
        await s.write("Admin/StopReason/AckDateTime", NULL_TIME if a is None or a.ack_at is None else a.ack_at)
        await s.write("Admin/StopReason/Trigger", False if a is None else a.active)

    async def _write_last_result(self, r: dict[str, Any] | None) -> None:
        s = self._space
        if s is None or r is None:
            return
        measured = r.get("measured_deviation") or {}
        values: dict[str, Any] = {
            "RequestId": str(r.get("request_id") or ""), "Recipe": r["recipe"],
            "PartId": r["part_id"], "CarId": r.get("car_id") or "", "Ok": bool(r["ok"]), "ErrorCode": int(r["error_code"]),
            "Reason": r.get("reason") or "", "MeasuredDeviation": _six(measured),
            "CycleTime": float(r["cycle_time_s"]), "CalibrationVersion": r.get("calibration_version") or "",
            "FinishedAt": datetime.fromisoformat(r["finished_at"]) if r.get("finished_at") else NULL_TIME,
            **{f"Measured/{k}": float(measured.get(k, 0.0)) for k in DEVIATION_KEYS},
            "CycleId": int(r["cycle_id"]),  # last: when it changes, every field above is this cycle's (the trigger)
        }  # fmt: skip
        # a cycle that measured nothing has no figures: BadNoData (no value), not a Good 0.0 (a perfect install)
        figures = ua.StatusCodes.Good if measured else ua.StatusCodes.BadNoData
        assert self._publishing is not None
        async with self._publishing.batch():  # one notification: no subscriber sees some fields of a cycle alone
            for name, value in values.items():
                status = figures if name.startswith("Measured/") else ua.StatusCodes.Good
                await s.write(f"Cycle/LastResult/{name}", value, status=status)

    # -- methods ---------------------------------------------------------------------------------

    def _callbacks(self) -> dict[str, Any]:
        out: dict[str, Any] = {m.path: self._command_cb(m.command) for m in METHODS if m.command is not None}
        out["SetUnitMode"] = self._set_unit_mode
        out["Cycle/StartCycle"] = self._start_cycle
        out["Cycle/GetResult"] = self._get_result
        return out

    async def _refused(self, err: Refused, what: str) -> ua.StatusCode:
        log.info("OPC UA: %s by %s refused: %s", what, caller(), err.reason)
        if self._space is not None:
            await self._space.write("Cycle/LastRefusal", f"{datetime.now(UTC).isoformat()} {what}: {err.reason}")
        return ua.StatusCode(getattr(ua.StatusCodes, err.status))

    def _command_cb(self, command: PackMLCommand) -> Any:
        async def call(parent: ua.NodeId, *args: ua.Variant) -> ua.StatusCode | list[ua.Variant]:
            try:
                await self._cell.command(command, actor=caller())
            except Refused as err:
                return await self._refused(err, command.name.title())
            return []

        return call

    async def _set_unit_mode(self, parent: ua.NodeId, *args: ua.Variant) -> ua.StatusCode | list[ua.Variant]:
        if len(args) != 1:
            return ua.StatusCode(ua.StatusCodes.BadArgumentsMissing)
        raw = args[0].Value if isinstance(args[0], ua.Variant) else args[0]
        if isinstance(raw, bool) or not isinstance(raw, int) or raw not in {int(m) for m in UNIT_MODES}:
            return await self._refused(Refused("BadInvalidArgument", f"UnitMode {raw!r} is not 1, 2 or 3"), "SetUnitMode")
        try:
            await self._cell.change_mode(UnitMode(raw), actor=caller())
        except Refused as err:
            return await self._refused(err, "SetUnitMode")
        return []

    async def _start_cycle(self, parent: ua.NodeId, *args: ua.Variant) -> ua.StatusCode | list[ua.Variant]:
        if len(args) != 4:
            return ua.StatusCode(ua.StatusCodes.BadArgumentsMissing)
        recipe, part_id, car_id, request_id = (_text(a).strip() for a in args)
        if not request_id or not part_id:
            what = "RequestId" if not request_id else "PartId"
            return await self._refused(Refused("BadInvalidArgument", f"{what} is empty; give one"), "StartCycle")
        if len(request_id) > 64:
            return await self._refused(Refused("BadInvalidArgument", "RequestId is longer than 64 characters"), "StartCycle")
        try:
            cycle_id = await self._cell.start_cycle(recipe, part_id, car_id or None, request_id, actor=caller())
        except Refused as err:
            return await self._refused(err, f"StartCycle {request_id}")
        return [ua.Variant(cycle_id, ua.VariantType.UInt32)]

    async def _get_result(self, parent: ua.NodeId, *args: ua.Variant) -> ua.StatusCode | list[ua.Variant]:
        if len(args) != 1:
            return ua.StatusCode(ua.StatusCodes.BadArgumentsMissing)
        known, r = await self._cell.result_for_request(_text(args[0]))
        if not known:
            return ua.StatusCode(ua.StatusCodes.BadNotFound)
        measured = (r or {}).get("measured_deviation") or {}
        return [
            ua.Variant(r is not None, ua.VariantType.Boolean),
            ua.Variant(bool(r and r["ok"]), ua.VariantType.Boolean),
            ua.Variant(int(r["error_code"]) if r else 0, ua.VariantType.UInt16),
            ua.Variant((r or {}).get("reason") or "", ua.VariantType.String),
            ua.Variant(_six(measured), ua.VariantType.Double),
            ua.Variant(float(r["cycle_time_s"]) if r else 0.0, ua.VariantType.Double),
        ]

    async def _acknowledge(self, uid: str, comment: str) -> Alarm:
        return await self._cell.acknowledge(uid, actor=caller(), comment=comment)


