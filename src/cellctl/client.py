"""A small HTTP client of the cell service for the CLI (and scripts): status, commands, cycles, jobs, events."""

from __future__ import annotations

import json
import os
import re
import ssl
import time
import uuid
from collections.abc import Callable, Iterator
from datetime import datetime
from pathlib import Path
from typing import Any

import httpx

DEFAULT_URL = "http://127.0.0.1:8080"
TOKEN_ENV = "CELLCTL_TOKEN"
URL_ENV = "CELLCTL_URL"


def service_url(given: str | None, api_host: str | None = None, api_port: int | None = None, tls: bool = False) -> str:
    """The service's URL: ``given``, else $CELLCTL_URL, else the configuration's [api] (a wildcard host as loopback;
    ``https`` when it serves TLS)."""
    if given:
        return given
    if os.environ.get(URL_ENV):
        return os.environ[URL_ENV]
    if api_port is None:
        return DEFAULT_URL
    host = api_host if api_host and api_host not in ("0.0.0.0", "::", "") else "127.0.0.1"
    return f"{'https' if tls else 'http'}://{host}:{api_port}"


class ServiceError(RuntimeError):
    """The service answered with an error (the message carries its detail) or could not be reached."""


_PEM_CERT = re.compile(r"-----BEGIN CERTIFICATE-----.+?-----END CERTIFICATE-----", re.S)


def trusting_ca(pem: Path) -> ssl.SSLContext:
    """A client context trusting the CA certificates of the PEM file ``pem`` (hostname checked)."""
    try:
        return ssl.create_default_context(cafile=str(pem))
    except (OSError, ssl.SSLError) as err:
        raise ServiceError(f"--ca {pem}: cannot use it as the CA that signed the service's certificate ({err}); "
                           "give the PEM file of the plant's CA") from None


def pinned_to(cert: Path) -> ssl.SSLContext:
    """A client context trusting exactly the first certificate of ``cert`` (the service's own, chain first), under
    whatever name it was issued for: the CLI on the cell's computer reaches its service on loopback."""
    try:
        first = _PEM_CERT.search(cert.read_text(encoding="ascii", errors="replace"))
    except OSError as err:
        raise ServiceError(f"api.tls_cert {cert}: cannot read the service's certificate to trust it ({err.strerror}); run "
                           "the CLI from serve's --workdir (or set $CELLCTL_WORKDIR), or give --url https://... with --ca") from None
    if first is None:
        raise ServiceError(f"api.tls_cert {cert}: no PEM certificate in it; give the certificate the service serves")
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    ctx.check_hostname = False  # the certificate itself is the trust anchor: only the holder of its key gets through
    ctx.verify_flags |= ssl.VERIFY_X509_PARTIAL_CHAIN
    ctx.load_verify_locations(cadata=first.group(0))
    return ctx


def _detail(r: httpx.Response) -> str:
    """The ``detail`` of an error answer, else its text."""
    try:
        body = r.json()
    except ValueError:
        return r.text
    return str(body.get("detail", r.text)) if isinstance(body, dict) else r.text


_EXPIRED, _NOT_YET_VALID = 10, 9  # OpenSSL's X509_V_ERR_CERT_HAS_EXPIRED, X509_V_ERR_CERT_NOT_YET_VALID
_NAME_MISMATCH = frozenset({62, 63, 64})  # X509_V_ERR_HOSTNAME_MISMATCH, _EMAIL_, _IP_ADDRESS_MISMATCH
_UNTRUSTED = frozenset({2, 18, 19, 20, 21})  # no issuer found, self-signed leaf or chain, leaf signature unverifiable


def _cause(err: BaseException, kind: type[BaseException]) -> BaseException | None:
    """The first exception of type ``kind`` in ``err``'s chain (httpx wraps httpcore, which wraps ssl or the OS)."""
    seen: set[int] = set()
    e: BaseException | None = err
    while e is not None and id(e) not in seen:
        if isinstance(e, kind):
            return e
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return None


def _what_failed(err: httpx.HTTPError) -> str:
    """What went wrong, from OpenSSL's verification reason or the OS's error only: never the exception's text, which
    may quote the request (h11 quotes an illegal header value, the bearer token)."""
    verify = _cause(err, ssl.SSLCertVerificationError)
    if isinstance(verify, ssl.SSLCertVerificationError):
        return f"CERTIFICATE_VERIFY_FAILED: {verify.verify_message}"
    if isinstance(err, httpx.TimeoutException):
        return f"no answer in time ({type(err).__name__})"
    os_err = _cause(err, OSError)
    if isinstance(os_err, OSError) and os_err.strerror:
        return os_err.strerror
    return type(err).__name__


def _reach_hint(url: str, err: httpx.HTTPError) -> str:
    """What to check when the service could not be reached: its certificate (by OpenSSL's reason), its scheme, or
    that it runs."""
    verify = _cause(err, ssl.SSLCertVerificationError)
    if isinstance(verify, ssl.SSLCertVerificationError):
        code = verify.verify_code
        if code == _EXPIRED:
            return ("its HTTPS certificate (or its CA's) has expired, or this computer's clock is wrong: have the "
                    "plant's CA issue a new api.tls_cert for the cell (another --ca does not help)")
        if code == _NOT_YET_VALID:
            return ("its HTTPS certificate is not valid yet: check the clock of this computer and of the cell, or have "
                    "api.tls_cert issued valid from now")
        if code in _NAME_MISMATCH:
            host = httpx.URL(url).host
            return (f"its HTTPS certificate is not issued for {host!r}: give --url with a name or address the "
                    "certificate holds (its subjectAltName), or have api.tls_cert issued for this one")
        if code in _UNTRUSTED:
            return "its HTTPS certificate is not trusted: give --ca with the PEM of the CA that signed it, or $SSL_CERT_FILE"
        return f"its HTTPS certificate was refused ({verify.verify_message}): check api.tls_cert and --ca"
    if url.startswith("http://") and isinstance(err, httpx.RemoteProtocolError):
        return "if it serves HTTPS ([api] tls_cert), use https://"
    return "is `cellctl serve` running?"


def clean_token(token: str | None, source: str) -> str | None:
    """The bearer token without surrounding white space (a CR or blank from a file or a copy-paste; the service
    strips it too); None if empty. ServiceError naming ``source``, never the value, if it holds a control or
    non-ASCII character: it cannot travel in an HTTP header."""
    value = (token or "").strip()
    if any(not (" " <= c <= "~") for c in value):
        raise ServiceError(f"{source} holds control or non-ASCII characters, which an HTTP header cannot carry: give "
                           "the token as the service's [api] tokens hold it (printable ASCII)")
    return value or None


class CellClient:
    """Talks to a running ``cellctl serve``. ``token`` defaults to $CELLCTL_TOKEN (see :func:`clean_token`)."""

    def __init__(self, url: str = DEFAULT_URL, token: str | None = None, timeout_s: float = 30.0,
                 verify: ssl.SSLContext | bool = True) -> None:  # fmt: skip
        self.url = url.rstrip("/")
        given = (token, "--token") if token is not None else (os.environ.get(TOKEN_ENV), f"${TOKEN_ENV}")
        self._token = clean_token(*given)
        self._verify, self._timeout_s = verify, timeout_s
        try:
            self._http = httpx.Client(base_url=self.url, timeout=timeout_s, verify=verify)
        except (httpx.InvalidURL, ValueError) as err:  # e.g. "Invalid port: '19x'"
            raise ServiceError(f"--url {url!r} (or ${URL_ENV}) is not a valid URL ({err}): give e.g. {DEFAULT_URL}") from None

    def another(self) -> CellClient:
        """A second client of the same service, token and trust (e.g. for the event stream beside the requests)."""
        return CellClient(self.url, self._token, self._timeout_s, self._verify)

    def close(self) -> None:
        self._http.close()

    def _headers(self, extra: dict[str, str] | None = None) -> dict[str, str]:
        h = dict(extra or {})
        if self._token:
            h["Authorization"] = f"Bearer {self._token}"
        return h

    def _call(self, method: str, path: str, **kw: Any) -> Any:
        """One request with the token (when given), its JSON answer; a :class:`ServiceError` that says what went wrong."""
        kw["headers"] = self._headers(kw.get("headers"))
        try:
            r = self._http.request(method, path, **kw)
        except httpx.HTTPError as err:  # its text only without the token: h11 quotes a header it refuses
            why = _what_failed(err) if self._token else str(err)
            raise ServiceError(f"cannot reach the cell service at {self.url}: {why} ({_reach_hint(self.url, err)})") from None
        except httpx.InvalidURL as err:
            raise ServiceError(f"{method} {path}: not a valid URL under --url {self.url!r} ({err})") from None
        if r.status_code >= 400:
            raise ServiceError(f"{method} {path} -> {r.status_code}: {_detail(r)}{self._token_hint(r.status_code)}")
        try:
            return r.json()
        except ValueError:
            raise ServiceError(
                f"{method} {path}: {self.url} answered something that is not JSON "
                f"({r.headers.get('content-type', 'no content type')}): is --url the cell service?"
            ) from None

    def _token_hint(self, status_code: int) -> str:
        """What the CLI user can do about a 401: which token source to check, or that none was given."""
        if status_code != 401:
            return ""
        if self._token:
            return f" (the token given by --token or ${TOKEN_ENV} was refused: check it)"
        return f" (no token given: set ${TOKEN_ENV} or pass --token)"

    def status(self) -> dict[str, Any]:
        return self._call("GET", "/status")

    def command(self, name: str) -> dict[str, Any]:
        return self._call("POST", f"/commands/{name}", headers=self._headers())

    def start_cycle(
        self, recipe: str, part_id: str, *, key: str | None = None, wait: bool = True, timeout_s: float = 300.0
    ) -> dict[str, Any]:
        headers = self._headers({"Idempotency-Key": key or uuid.uuid4().hex})
        params = {"wait": str(wait).lower(), "timeout_s": timeout_s}
        return self._call(
            "POST", "/cycle", json={"recipe": recipe, "part_id": part_id}, headers=headers, params=params,
            timeout=timeout_s + 10.0,
        )  # fmt: skip

    def cycle(self, cycle_id: int) -> dict[str, Any]:
        return self._call("GET", f"/cycles/{cycle_id}")

    # part traceability
    def parts(
        self,
        *,
        car_id: str | None = None,
        part_id: str | None = None,
        since: datetime | None = None,
        until: datetime | None = None,
        page_size: int = 100,
        applied: Callable[[str], None] | None = None,
    ) -> Iterator[dict[str, Any]]:
        """Every install matching the filters (``GET /parts``), oldest first, fetched a page at a time as it is iterated.

        ``since``/``until`` must be timezone-aware (the window is on when the install ended: since
        inclusive, until exclusive). The cell applies ``until`` no later than its own clock: ``applied`` is
        called with the bound it used (the next window's ``since``), which the later pages keep.
        """
        params: dict[str, Any] = {"limit": page_size}
        for name, value in (("car_id", car_id), ("part_id", part_id), ("since", since), ("until", until)):
            if value is not None:
                params[name] = value.isoformat() if isinstance(value, datetime) else value
        while True:
            page = self._call("GET", "/parts", params=params, headers=self._headers())
            if until is not None and page.get("until") and params.get("until") != page["until"]:
                params["until"] = page["until"]
                if applied is not None:
                    applied(page["until"])
            yield from page["installs"]
            if page["next"] is None:
                return
            params["after"] = page["next"]

    def part(self, part_id: str) -> dict[str, Any]:
        """Every install of one glass (``GET /part-history?part_id=``: a query carries any id, where a URL path folds
        "." and ".."); a :class:`ServiceError` saying "no glass with part id ..." when none is recorded."""
        history = self._call("GET", "/part-history", params={"part_id": part_id}, headers=self._headers())
        if not isinstance(history, dict) or history.get("part_id") != part_id or not isinstance(history.get("installs"), list):
            raise ServiceError(f"GET /part-history: {self.url} answered something that is not the history of glass "
                               f"{part_id!r}: is --url the cell service?")  # fmt: skip
        return history

    # commissioning jobs
    def plan_job(self, procedure: str, options: dict[str, Any], *, poses: bool = False) -> dict[str, Any]:
        body = {"procedure": procedure, "options": options}
        return self._call("POST", "/jobs/plan", json=body, params={"poses": str(poses).lower()}, headers=self._headers())

    def start_job(self, procedure: str, options: dict[str, Any]) -> dict[str, Any]:
        return self._call("POST", "/jobs", json={"procedure": procedure, "options": options}, headers=self._headers())

    def job(self, job_id: int) -> dict[str, Any]:
        return self._call("GET", f"/jobs/{job_id}", headers=self._headers())

    def cancel_job(self, job_id: int) -> dict[str, Any]:
        return self._call("POST", f"/jobs/{job_id}/cancel", headers=self._headers())

    def answer_prompt(self, job_id: int, prompt_id: int, action: str, value: float | None = None) -> dict[str, Any]:
        return self._call(
            "POST", f"/jobs/{job_id}/prompts/{prompt_id}", json={"action": action, "value": value}, headers=self._headers()
        )

    def events(self, *, read_timeout_s: float = 15.0) -> Iterator[tuple[str, dict[str, Any]]]:
        """The service's event stream (server-sent events) as (kind, data) pairs, until the caller stops."""
        timeout = httpx.Timeout(10.0, read=read_timeout_s)
        try:
            with self._http.stream("GET", "/events", headers=self._headers({"Accept": "text/event-stream"}), timeout=timeout) as r:
                if r.status_code >= 400:
                    raise ServiceError(f"GET /events -> {r.status_code}{self._token_hint(r.status_code)}")
                kind, data = "message", ""
                for line in r.iter_lines():
                    if line.startswith("event:"):
                        kind = line[6:].strip()
                    elif line.startswith("data:"):
                        data += line[5:].strip()
                    elif not line:
                        if data:
                            yield kind, json.loads(data)
                        kind, data = "message", ""
        except httpx.HTTPError as err:
            why = _what_failed(err) if self._token else str(err)
            raise ServiceError(f"the event stream of {self.url} ended: {why} ({_reach_hint(self.url, err)})") from None

    def bring_to_execute(self) -> str:
        """Send Clear/Reset/Start as the state needs to reach Execute; returns the state reached."""
        plan = {"ABORTED": ["clear", "reset", "start"], "STOPPED": ["reset", "start"], "COMPLETE": ["reset", "start"],
                "IDLE": ["start"], "HELD": ["unhold"], "SUSPENDED": ["unsuspend"]}  # fmt: skip
        state = self.status()["state"]
        for cmd in plan.get(state, []):
            self.command(cmd)
            state = self.wait_settled()
        return state

    def wait_settled(self, timeout_s: float = 30.0) -> str:
        """Wait until the cell leaves its acting state (Clearing, Resetting, Starting, ...)."""
        deadline = time.monotonic() + timeout_s
        while True:
            state = self.status()["state"]
            if not state.endswith("ING") or time.monotonic() > deadline:
                return state
            time.sleep(0.05)
