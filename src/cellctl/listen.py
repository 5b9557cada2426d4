"""Why a server of the service ([api], [plc], [opcua]) cannot listen on its host and port, said with the setting to
change: one text for ``config check --secrets`` (a trial bind) and ``serve`` (the failed start)."""

from __future__ import annotations

import errno
import os
import socket


def listen_problem(section: str, host: str, port: int, err: OSError) -> str:
    """What a failed bind of ``host``:``port`` means (``err``: the OS's error) and which setting of ``section``
    (e.g. "[api]") to change: the host for an address not of this machine, the port for one in use or privileged."""
    where, setting = f"{host}:{port}", f"{section} port"
    why = err.strerror if isinstance(err, socket.gaierror) or not err.errno else os.strerror(err.errno)  # not asyncio's text
    if isinstance(err, socket.gaierror) or err.errno == errno.EADDRNOTAVAIL:
        return f"{section} host {host!r} is not an address of this machine ({why}); set it to one of them"
    if err.errno == errno.EADDRINUSE:
        return f"another program listens on {where} ({setting}): stop it or choose another port"
    if err.errno == errno.EACCES:
        return (f"cannot listen on {where} ({setting}): {why}; choose a port of 1024 or above, or give the service "
                "CAP_NET_BIND_SERVICE (as deploy/cellctl.service does)")
    return f"cannot listen on {where} ({setting}): {why}; set {section} host to an address of this machine"


def port_problem(setting: str, host: str, port: int) -> str | None:
    """Why a server could not listen on ``host``:``port`` now (tried with a bind, closed at once); None if it could.
    ``setting``: the port's setting, e.g. "[api] port"."""
    try:
        family, kind, proto, _, addr = socket.getaddrinfo(host or None, port, type=socket.SOCK_STREAM,
                                                           flags=socket.AI_PASSIVE)[0]  # fmt: skip
        with socket.socket(family, kind, proto) as sock:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the servers do: TIME_WAIT is no obstacle
            sock.bind(addr)
    except OSError as err:  # socket.gaierror included: a name that does not resolve
        return listen_problem(setting.split()[0], host, port, err)
    return None
