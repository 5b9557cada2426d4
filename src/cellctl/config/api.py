"""The REST API and dashboard server: where it listens, its bearer tokens, its request limits."""

from __future__ import annotations

import enum
import logging
import os
import ssl
import stat
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from pydantic import Field, ValidationInfo, field_validator, model_validator

from cellctl.config.certificates import certificate_dates, key_certificate_index
from cellctl.config.devices import is_loopback
from cellctl.config.types import ListenHost, StrictModel, check_unique

log = logging.getLogger(__name__)

MIN_TOKEN_LENGTH = 16
SIM_DEFAULT_TOKEN = "sim-operator-token-change-me"
"""The simulated cell's operator token (config/sim.toml and the code default): never valid on a real cell."""
KNOWN_DEFAULT_TOKENS = frozenset({
    SIM_DEFAULT_TOKEN,
    "replace-with-a-long-random-operator-token",  # deploy/cellctl.env.example
    "replace-with-a-long-random-integrator-token",
})  # fmt: skip
PLACEHOLDER_MARKS = ("change-me", "changeme", "change_me", "replace-with", "replace_me", "placeholder", "example")
MIN_DISTINCT_CHARACTERS = 8
TOKEN_FILE_MAX_BYTES = 4096
MAKE_A_TOKEN = "python3 -c 'import secrets; print(secrets.token_urlsafe(32))'"
DEFAULT_MAX_BODY_BYTES = 64 * 1024
"""The largest request body (bytes): the API's bodies (a cycle request, a job request, a prompt answer) are
below 1 kB each; 64 kB leaves room for long ids and options without letting a client fill the memory."""


class ApiRole(enum.StrEnum):
    """What a bearer token may do (the OPC UA users' role names; ``cellctl.api.auth.ROUTE_ROLES`` is the route table).

    Each role may do all that the roles before it may: ``viewer`` reads (where reads are closed),
    ``operator`` runs production, ``engineer`` also changes what production runs on.
    """

    viewer = "viewer"
    operator = "operator"
    engineer = "engineer"

    def allows(self, needed: ApiRole) -> bool:
        """Whether a token of this role may use a route that needs ``needed``."""
        order = list(ApiRole)
        return order.index(self) >= order.index(needed)


ROLE_RIGHTS = {
    ApiRole.viewer: "reads only, where reads are closed",
    ApiRole.operator: "also cycles, PackML commands, unit mode changes and alarm acknowledgement",
    ApiRole.engineer: "also SPC reset, calibration and teaching jobs and their prompts",
}
"""What each role adds, in words (errors, ``cellctl config check``, docs)."""
DEFAULT_ROLE = ApiRole.engineer
"""A token without ``role`` may do everything, as before roles existed; shipped configs name the role."""


class TokenUnavailable(ValueError):
    """A token named in the configuration cannot be read, or what was read is unfit. The message says which and the fix."""


def token_weakness(value: str) -> str | None:
    """Why ``value`` is unfit as a bearer token of a real cell (None: fit).

    The one rule for every token a cell reads from its environment or a file: at least
    ``MIN_TOKEN_LENGTH`` characters, no whitespace or control characters (it travels in a header),
    not a shipped default or a placeholder ("change-me", "replace-with..."), and at least
    ``MIN_DISTINCT_CHARACTERS`` different characters (not "aaaa...").
    """
    if len(value) < MIN_TOKEN_LENGTH:
        return f"it has {len(value)} characters, fewer than {MIN_TOKEN_LENGTH}"
    if any(c.isspace() or not c.isprintable() for c in value):
        return "it contains whitespace or control characters (it must travel in an HTTP header)"
    low = value.lower()
    if value in KNOWN_DEFAULT_TOKENS or any(mark in low for mark in PLACEHOLDER_MARKS):
        return "it is a shipped default or a placeholder, known to anyone who has read the examples"
    if len(set(value)) < MIN_DISTINCT_CHARACTERS:
        return f"it has fewer than {MIN_DISTINCT_CHARACTERS} different characters"
    return None


class ApiToken(StrictModel):
    """A bearer token. ``name`` is the actor recorded in the audit log; ``role`` says what it may do (:class:`ApiRole`).

    Exactly one source: ``token_env`` (an environment variable, e.g. set from /etc/cellctl/cellctl.env),
    ``token_file`` (a file whose content is the token; not readable by every user), or ``token``
    (the value itself, in the configuration file: the simulated cell only; a hardware cell refuses it).
    A token from the environment or a file must pass :func:`token_weakness`.
    """

    name: str = Field(min_length=1, max_length=64)
    token: str | None = None
    token_env: str | None = Field(None, pattern=r"^[A-Za-z_][A-Za-z0-9_]*$", max_length=128)
    token_file: Path | None = None
    role: ApiRole = DEFAULT_ROLE

    @field_validator("role", mode="before")
    @classmethod
    def _known_role(cls, value: Any, info: ValidationInfo) -> Any:
        if value not in [r.value for r in ApiRole]:
            rights = "; ".join(f"{r.value}: {ROLE_RIGHTS[r]}" for r in ApiRole)
            raise ValueError(f"token '{info.data.get('name', '?')}': {value!r} is not a role; give 'viewer', 'operator' "
                             f"or 'engineer' ({rights})")
        return value

    @model_validator(mode="after")
    def _one_source(self) -> ApiToken:
        given = [k for k in ("token", "token_env", "token_file") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError(
                f"token '{self.name}': give exactly one of token_env, token_file or token (got {given or 'none'})"
            )
        if self.token is not None and len(self.token) < MIN_TOKEN_LENGTH:
            raise ValueError(f"token '{self.name}': must be at least {MIN_TOKEN_LENGTH} characters")
        return self

    @property
    def source(self) -> str:
        """Where the value comes from, as the configuration names it."""
        if self.token_env is not None:
            return f"environment variable {self.token_env}"
        if self.token_file is not None:
            return f"file {self.token_file}"
        return "the configuration file (token)"

    def secret(self, root: Path | None = None) -> str:
        """The token's value, read now (environment or file; a relative ``token_file`` taken from ``root``, the folder of
        ``serve --workdir``, else the current folder). Raises :class:`TokenUnavailable` naming the source and the fix."""
        if self.token is not None:
            return self.token
        path = None if self.token_file is None else (root or Path()) / self.token_file
        return read_secret(f"api.tokens '{self.name}'", env=("token_env", self.token_env), file=("token_file", path))


def read_secret(where: str, *, env: tuple[str, str | None], file: tuple[str, Path | None], what: str = "token") -> str:
    """A secret from the environment variable ``env[1]`` or else the file ``file[1]``, checked by :func:`token_weakness`.

    ``where`` and the field names (``env[0]``, ``file[0]``) name the setting in every error, with its fix.
    """
    (env_field, variable), (file_field, path) = env, file
    if variable is not None:
        value = os.environ.get(variable, "").strip()
        if not value:
            raise TokenUnavailable(
                f"{where}: {env_field}: environment variable {variable} is not set or empty; set it in the "
                "service's environment (/etc/cellctl/cellctl.env, see deploy/cellctl.env.example)"
            )
        field, source = env_field, f"environment variable {variable}"
    else:
        path = Path(path).absolute()  # type: ignore[arg-type]  # the file it read, named (relative: from the current folder)
        value = _read_token_file(f"{where}: {file_field}", path)
        field, source = file_field, f"file {path}"
    weak = token_weakness(value)
    if weak is not None:
        raise TokenUnavailable(f"{where}: {field}: the {what} in {source} is refused: {weak}; make a new one with {MAKE_A_TOKEN}")
    return value


def _read_token_file(where: str, path: Path) -> str:
    """The secret in ``path`` (surrounding whitespace, e.g. a final newline, removed); ``where`` names the setting."""
    fix = f"write the secret into it (one line, chmod 600, owned by the service's user; make one with {MAKE_A_TOKEN})"
    try:
        st = path.stat()
    except FileNotFoundError:
        raise TokenUnavailable(f"{where}: {path} does not exist; {fix}") from None
    except OSError as err:
        raise TokenUnavailable(f"{where}: {path} cannot be read ({err.strerror}); {fix}") from None
    if not stat.S_ISREG(st.st_mode):
        raise TokenUnavailable(f"{where}: {path} is not a regular file; {fix}")
    if (problem := open_to_everyone(path, st)) is not None:
        raise TokenUnavailable(f"{where}: {problem}")
    if st.st_size > TOKEN_FILE_MAX_BYTES:
        raise TokenUnavailable(f"{where}: {path} has {st.st_size} bytes; the file holds one secret")
    try:
        raw = path.read_bytes()
    except OSError as err:
        raise TokenUnavailable(f"{where}: {path} cannot be read ({err.strerror}); {fix}") from None
    try:
        value = raw.decode("utf-8").strip()
    except UnicodeDecodeError:
        raise TokenUnavailable(f"{where}: {path} is not UTF-8 text; {fix}") from None
    if not value:
        raise TokenUnavailable(f"{where}: {path} is empty; {fix}")
    return value


def open_to_everyone(path: Path, st: os.stat_result) -> str | None:
    """Why a secret file (token, password, key) of mode ``st`` is refused: every user may read or write it; else None."""
    if st.st_mode & (stat.S_IROTH | stat.S_IWOTH):
        return (f"{path} can be read or written by every user (mode {stat.S_IMODE(st.st_mode):04o}); "
                f"chmod 600 {path} (or 640 with the service's group)")
    return None


class ApiConfig(StrictModel):
    """Where the service listens, who may change things, whether reads need a token, how large a request may be."""

    host: ListenHost = "127.0.0.1"
    port: int = Field(8080, ge=0, le=65535)
    tokens: tuple[ApiToken, ...] = (ApiToken(name="operator", token=SIM_DEFAULT_TOKEN),)
    open_reads: bool = True  # GET routes, /health details and /metrics without a token, for a trusted cell network
    cycle_wait_max_s: float = Field(600.0, gt=0)
    max_body_bytes: int = Field(DEFAULT_MAX_BODY_BYTES, ge=1024, le=16 * 1024 * 1024)
    tls_cert: Path | None = None  # PEM certificate (chain first) the API serves HTTPS with; relative: from serve --workdir
    tls_key: Path | None = None  # its PEM private key, unencrypted, not readable by every user (chmod 600)

    @model_validator(mode="after")
    def _tls_pair(self) -> ApiConfig:
        given = [f for f in ("tls_cert", "tls_key") if getattr(self, f) is not None]
        if len(given) == 1:
            missing = "tls_key" if given == ["tls_cert"] else "tls_cert"
            raise ValueError(f"{given[0]} is set but {missing} is not: give both api.tls_cert (the certificate, PEM) "
                             "and api.tls_key (its private key) to serve HTTPS, or neither")
        return self

    @model_validator(mode="after")
    def _tokens(self) -> ApiConfig:
        if not self.tokens:
            raise ValueError("tokens: give at least one token; mutating routes need a bearer token")
        check_unique("tokens", "name", [t.name for t in self.tokens])
        for field in ("token", "token_env", "token_file"):
            given = [(t.name, getattr(t, field)) for t in self.tokens if getattr(t, field) is not None]
            if field == "token_file":
                given = [(name, os.path.normpath(path)) for name, path in given]
            problem = shared_token(given, f"the same {field}", where="tokens")
            if problem is not None:
                raise ValueError(problem)
        return self

    def hardware_problems(self) -> list[str]:
        """What a hardware cell refuses in this section: tokens not from the environment or a file (field: message)."""
        if "tokens" not in self.model_fields_set:
            return [(
                "api.tokens: no token is configured, so the simulated cell's default token would open the cell; add "
                '[[api.tokens]] entries with token_env (e.g. token_env = "CELLCTL_TOKEN") or token_file '
                "(see config/hardware.example.toml)"
            )]
        problems = []
        for i, t in enumerate(self.tokens):
            if t.token is not None:
                problems.append(
                    f"api.tokens.{i}.token: token '{t.name}' is written in the configuration file; a hardware cell reads "
                    "its tokens from the environment (token_env) or a file (token_file): move it there and name the "
                    "variable or the file"
                )
            elif t.token_file is not None and not t.token_file.is_absolute():
                problems.append(f"api.tokens.{i}.token_file: give an absolute path (got '{t.token_file}')")
        return problems

    def rooted(self, root: Path) -> ApiConfig:
        """This section with its relative files (token files, TLS certificate and key) taken from ``root``, the folder
        of ``serve --workdir``, as every other relative path of the configuration is."""
        base = root.resolve()
        update: dict[str, Any] = {f: base / p for f in ("tls_cert", "tls_key")
                                  if (p := getattr(self, f)) is not None and not p.is_absolute()}  # fmt: skip
        tokens = tuple(t.model_copy(update={"token_file": base / t.token_file})
                       if t.token_file is not None and not t.token_file.is_absolute() else t for t in self.tokens)  # fmt: skip
        if tokens != self.tokens:
            update["tokens"] = tokens
        return self.model_copy(update=update) if update else self

    def tls_problems(self, root: Path) -> list[str]:
        """Why the TLS certificate and key (paths from ``root``) cannot serve HTTPS now; [] when they can or without TLS."""
        api = self.rooted(root)
        if api.tls_cert is None or api.tls_key is None:
            return []
        problems = []
        for field, path in (("tls_cert", api.tls_cert), ("tls_key", api.tls_key)):
            try:
                st = path.stat()
                if not stat.S_ISREG(st.st_mode):
                    problems.append(f"api.{field}: {path} is not a regular file; give the PEM file's path")
                elif field == "tls_key" and (problem := open_to_everyone(path, st)) is not None:
                    problems.append(f"api.{field}: {problem}")
                else:
                    path.open("rb").close()
            except OSError as err:
                problems.append(f"api.{field}: {path} cannot be read ({err.strerror or err}); give the path of a PEM "
                                "file the service's user can read")  # fmt: skip
        if problems:
            return problems
        try:
            ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER).load_cert_chain(api.tls_cert, api.tls_key, password=_no_passphrase)
        except _PassphraseAsked:
            return [f"api.tls_key: {api.tls_key} is encrypted with a passphrase, which the service cannot be given; "
                    f"write it unencrypted (openssl pkey -in {api.tls_key} -out new.pem), chmod 600"]
        except ssl.SSLError as err:
            if err.reason == "KEY_VALUES_MISMATCH":
                return [_key_mismatch(api.tls_cert, api.tls_key)]
            return [f"api.tls_cert, api.tls_key: {api.tls_cert} and {api.tls_key} are not a PEM certificate and its "
                    f"unencrypted PEM private key (OpenSSL: {err.reason or err}); give the files the plant's CA issued"]
        return _leaf_dates_problems(api.tls_cert)

    def plain_http_warning(self) -> str | None:
        """The warning for a hardware cell whose API listens beyond this machine without TLS; None otherwise."""
        if self.tls_cert is not None or is_loopback(self.host):
            return None
        return (f"api.host = {self.host!r} is reached from the network over plain HTTP: the bearer tokens (the "
                "engineer's too) travel in clear; set api.tls_cert and api.tls_key, or bind api.host = \"127.0.0.1\" "
                "behind a TLS proxy")

    def roles(self) -> dict[str, ApiRole]:
        """Each token's role by its name."""
        return {t.name: t.role for t in self.tokens}

    def role_notes(self) -> list[str]:
        """Each token's role, and a word when every token is an engineer (lines for ``cellctl config check``)."""
        lines = [", ".join(f"{t.name}: {t.role.value}" for t in self.tokens)]
        if all(t.role is ApiRole.engineer for t in self.tokens):
            lines.append('every API token is an engineer (all rights): for least privilege give the line\'s tokens '
                         'role = "operator" (or "viewer") in [[api.tokens]]')
        return lines

    def secrets(self, root: Path | None = None) -> tuple[tuple[str, str], ...]:
        """Every token as (name, value), read now (relative files from ``root``, see :meth:`ApiToken.secret`). Raises
        :class:`TokenUnavailable` naming every token that cannot be used."""
        out, problems = [], []
        for t in self.tokens:
            try:
                out.append((t.name, t.secret(root)))
            except TokenUnavailable as err:
                problems.append(str(err))
        shared = shared_token(out, "the same token value (read from their sources)")
        if shared is not None:
            problems.append(shared)
        if problems:
            raise TokenUnavailable("\n".join(problems))
        return tuple(out)


def _key_mismatch(cert_path: Path, key_path: Path) -> str:
    """What OpenSSL's KEY_VALUES_MISMATCH means here: a chain with the server's certificate not first, or another key."""
    own = key_certificate_index(cert_path, key_path)
    if own:
        return (f"api.tls_cert: {cert_path} is in the wrong order: the certificate of api.tls_key {key_path} is "
                f"certificate {own + 1} in it; the server's certificate must come first in "
                "api.tls_cert, the intermediate CA certificates after it")
    return f"api.tls_key: {key_path} is not the private key of api.tls_cert {cert_path}; give the certificate's own key"


class NotValidYet(str):
    """A problem line of :meth:`ApiConfig.tls_problems` saying api.tls_cert is not valid yet by this computer's clock:
    the clock stands behind (at boot, before NTP), so a start once it is right succeeds (``serve`` exits 1, not 2)."""

    __slots__ = ()


def _leaf_dates_problems(cert_path: Path) -> list[str]:
    """The served (first) certificate of ``cert_path`` outside its validity, as [problem] (a :class:`NotValidYet` when it
    starts after this computer's clock); a warning logged when it expires within EXPIRY_WARNING_DAYS; [] otherwise."""
    from cryptography import x509

    try:
        leaf = x509.load_pem_x509_certificates(cert_path.read_bytes())[0]
    except (OSError, ValueError, IndexError):  # OpenSSL has just loaded it: nothing more to say
        return []
    fix = "have the plant's CA issue a new one, and restart the service"
    now = datetime.now(timezone.utc)
    problem, warning = certificate_dates(leaf, f"api.tls_cert: {cert_path}", fix, now=now)
    if warning is not None:
        log.warning("%s", warning)
    if problem is None:
        return []
    return [NotValidYet(problem) if now < leaf.not_valid_before_utc else problem]


class _PassphraseAsked(Exception):
    """OpenSSL asked for the passphrase of an encrypted key."""


def _no_passphrase() -> bytes:
    raise _PassphraseAsked  # never OpenSSL's prompt on the terminal of a service


def shared_token(tokens: list[tuple[str, object]], what: str, *, where: str = "api.tokens") -> str | None:
    """Two [[api.tokens]] entries (name, value) whose values are equal, named (never the value), or None."""
    first: dict[object, str] = {}
    for name, value in tokens:
        if value in first:
            return (f"{where}: '{first[value]}' and '{name}' have {what}: a request with it would be recorded in the "
                    f"audit log as '{first[value]}'s; give each entry its own token (make one with {MAKE_A_TOKEN})")
        first[value] = name
    return None
