"""Argument parsing shared by the ``cellctl`` subcommands: the parser class and the argument types."""

from __future__ import annotations

import argparse
import os
import re
import ssl
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

from cellctl.client import URL_ENV, CellClient, pinned_to, service_url, trusting_ca

if TYPE_CHECKING:
    from cellctl.config.schema import CellConfig

WORKDIR_ENV = "CELLCTL_WORKDIR"


def default_workdir() -> Path:
    """``$CELLCTL_WORKDIR``, else the current folder; absolute, so messages say where var/ is looked for."""
    return Path(os.environ.get(WORKDIR_ENV) or ".").resolve()


class CliParser(argparse.ArgumentParser):
    """An argparse parser that takes no abbreviated options (``--view`` is not ``--views``) and reports a
    bad argument on one line, ``cellctl calibrate camera: error: --views must be ≥ 1 (got 0)``, exit 2.

    Sub-parsers made with ``add_subparsers().add_parser`` are of this class too.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> NoReturn:
        message = re.sub(r"^argument ([^:]+): (must|expected)", r"\1 \2", message)
        sys.stderr.write(f"{self.prog}: error: {message}\n(`{self.prog} --help` lists the options)\n")
        sys.exit(2)


def add_remote_options(p: argparse.ArgumentParser) -> None:
    """``--url``, ``--token`` and ``--ca`` of a command that talks to the running service."""
    p.add_argument("--url", default=None,
                   help="the running service (default: $CELLCTL_URL, else the host and port of the configuration's [api])")  # fmt: skip
    p.add_argument("--token", default=None, help="bearer token (default: $CELLCTL_TOKEN)")
    p.add_argument("--ca", default=None, type=Path, metavar="PEM",
                   help="PEM of the CA that signed the service's HTTPS certificate (default: the system's CAs or "
                        "$SSL_CERT_FILE; without --url or $CELLCTL_URL, the configuration's own api.tls_cert)")  # fmt: skip


def remote_client(args: argparse.Namespace, config: CellConfig) -> CellClient:
    """The client of the service ``args`` name (``--url``, else $CELLCTL_URL, else the configuration's [api]).

    Over HTTPS it trusts ``--ca``; else, for the configuration's own [api] with ``tls_cert``, exactly that
    certificate (read from serve's workdir, as the service reads it); else the system's CAs.
    """
    api = config.api
    given = args.url or os.environ.get(URL_ENV)
    url = service_url(given, api.host, api.port, tls=api.tls_cert is not None)
    verify: ssl.SSLContext | bool = True
    if args.ca is not None:
        verify = trusting_ca(args.ca)
    elif not given and api.tls_cert is not None:
        cert = api.rooted(default_workdir()).tls_cert
        assert cert is not None
        verify = pinned_to(cert)
    return CellClient(url, args.token, verify=verify)


def whole_number(minimum: int) -> Callable[[str], int]:
    """An argparse type: a whole number not below ``minimum``."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number (got {text!r})") from None
        if v < minimum:
            raise argparse.ArgumentTypeError(f"must be ≥ {minimum} (got {v})")
        return v

    return parse


def positive_number(text: str) -> float:
    """An argparse type: a finite number above 0 (seconds, for instance)."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number (got {text!r})") from None
    if not v > 0 or v == float("inf"):
        raise argparse.ArgumentTypeError(f"must be > 0 (got {text})")
    return v


def port_number(text: str) -> int:
    """An argparse type: a TCP port, 0 (any free one) to 65535."""
    v = whole_number(0)(text)
    if v > 65535:
        raise argparse.ArgumentTypeError(f"must be a TCP port, 0 to 65535 (got {v})")
    return v


positive_int = whole_number(1)
non_negative_int = whole_number(0)
