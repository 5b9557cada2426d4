"""Starting the EGM peer's loop: the controller's address it prefers, and why a loop it started is gone."""

from __future__ import annotations

import asyncio
import ipaddress
import signal
import socket


async def resolve_ipv4(host: str | None, timeout_s: float) -> tuple[tuple[str, ...], str | None]:
    """The IPv4 addresses of ``host`` (an address or a name) and, if it gives none, why (None: resolved).

    ``timeout_s`` bounds a name lookup (s).
    """
    if not host:
        return (), None
    try:
        return (str(ipaddress.IPv4Address(host)),), None
    except ValueError:
        pass
    loop = asyncio.get_running_loop()
    try:
        infos = await asyncio.wait_for(
            loop.getaddrinfo(host, None, family=socket.AF_INET, type=socket.SOCK_DGRAM), max(timeout_s, 0.001)
        )
    except (OSError, asyncio.TimeoutError) as exc:
        return (), f"cannot resolve the controller's host {host!r} ({exc or 'timed out'})"
    ips = tuple(dict.fromkeys(str(info[4][0]) for info in infos))
    return ips, None if ips else f"the controller's host {host!r} has no IPv4 address"


def exit_reason(returncode: int) -> str:
    """How a child process ended, from its return code (negative: the signal that killed it)."""
    if returncode < 0:
        try:
            return f"killed by signal {-returncode} ({signal.Signals(-returncode).name})"
        except ValueError:
            return f"killed by signal {-returncode}"
    return f"exit code {returncode}"
