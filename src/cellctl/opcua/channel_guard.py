"""An asyncua Server that keeps a SecureChannel with security policy None to discovery when the config does
not list "None": GetEndpoints and FindServers answer (OPC UA Part 4, 5.4: discovery needs no security),
every other request gets BadSecurityPolicyRejected and the connection is closed.

asyncua 2.1 opens such a channel with its default policy None, which carries no permission rules
(``SecureConnection.select_policy``), so without this guard a session on it skipped the cell's roles.
"""

from __future__ import annotations

import logging
import socket
from typing import Any

from asyncua import Server, ua
from asyncua.crypto import uacrypto
from asyncua.crypto.security_policies import SecurityPolicyNone
from asyncua.server.binary_server_asyncio import BinaryServer, OPCUAProtocol
from asyncua.server.uaprocessor import UaProcessor
from asyncua.ua.ua_binary import nodeid_from_binary, struct_from_binary

log = logging.getLogger(__name__)

DISCOVERY = frozenset(
    ua.NodeId(i) for i in (ua.ObjectIds.GetEndpointsRequest_Encoding_DefaultBinary,
                           ua.ObjectIds.FindServersRequest_Encoding_DefaultBinary)
)  # fmt: skip
"""The requests a channel with policy None may carry when the config does not list "None"."""


class _DiscoveryOnlyOnNone(UaProcessor):
    """asyncua's processor, refusing all but discovery on a channel with policy None."""

    async def process_message(self, seqhdr: Any, body: Any) -> bool:
        if self._connection.security_policy.URI != SecurityPolicyNone.URI:
            return bool(await super().process_message(seqhdr, body))
        peek = body.copy()
        typeid = nodeid_from_binary(peek)
        if typeid in DISCOVERY:
            return bool(await super().process_message(seqhdr, body))
        request = struct_from_binary(ua.RequestHeader, peek)
        log.warning("OPC UA: refused %s from %s over security policy None, which [opcua] security_policies does not "
                    "list; the client must connect with a listed policy", ua.ObjectIdNames.get(typeid.Identifier, typeid),
                    self.name)  # fmt: skip
        fault = ua.ServiceFault()
        fault.ResponseHeader.ServiceResult = ua.StatusCode(ua.StatusCodes.BadSecurityPolicyRejected)
        self.send_response(request.RequestHandle, seqhdr, fault)
        return False  # the protocol closes the connection


class _GuardedProtocol(OPCUAProtocol):
    def connection_made(self, transport: Any) -> None:
        super().connection_made(transport)
        if self.processor is not None:  # None: refused at max_connections; no message has arrived yet
            self.processor = _DiscoveryOnlyOnNone(self.iserver, self.transport, self.limits)
            self.processor.set_policies(self.policies)


class _GuardedBinaryServer(BinaryServer):
    def _make_protocol(self) -> OPCUAProtocol:
        return _GuardedProtocol(iserver=self.iserver, policies=self._policies, clients=self.clients,
                                closing_tasks=self.closing_tasks, limits=self.limits)  # fmt: skip


class NoneDiscoveryOnlyServer(Server):
    """asyncua's Server whose connections keep a channel with policy None to discovery."""

    async def start(self) -> None:
        """asyncua 2.1's ``Server.start`` with the guarded binary server."""
        if self.iserver.certificate is not None:
            uacrypto.check_certificate(self.iserver.certificate, self._application_uri, socket.gethostname())
        await self._setup_server_nodes()
        await self.iserver.start()
        try:
            host, port = self._get_bind_socket_info()
            self.bserver = _GuardedBinaryServer(self.iserver, host, port, self.limits)  # type: ignore[arg-type]
            self.bserver.set_policies(self._policies)
            await self.bserver.start()
        except Exception:
            await self.iserver.stop()
            raise
