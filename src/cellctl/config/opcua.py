"""The plant's OPC UA server: endpoint, security policies, the server's certificate and its users."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field, model_validator

from cellctl.config.api import read_secret
from cellctl.config.types import ListenHost, StrictModel, check_unique

SecurityPolicy = Literal["Basic256Sha256_SignAndEncrypt", "Basic256Sha256_Sign", "None"]
SIM_DEFAULT_PASSWORD = "sim-opcua-password-change-me"
"""The simulated cell's OPC UA operator password (config/sim.toml): never valid on a real cell."""


class OpcUaUser(StrictModel):
    """A user of the OPC UA server; ``name`` goes into the audit log for every method it calls.

    A password user gives exactly one of ``password_env``, ``password_file`` or ``password`` (the value
    in the file: the simulated cell only); a certificate user gives ``certificate`` (its X.509 file, DER or PEM).
    ``role``: ``operator`` may call methods (commands, StartCycle, Acknowledge); ``viewer`` reads, subscribes and calls
        only what changes nothing (ConditionRefresh, GetResult).
    """

    name: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9][A-Za-z0-9_.@-]*$")
    role: Literal["operator", "viewer"] = "operator"
    password: str | None = None
    password_env: str | None = Field(None, pattern=r"^[A-Za-z_][A-Za-z0-9_]*$", max_length=128)
    password_file: Path | None = None
    certificate: Path | None = None

    @model_validator(mode="after")
    def _one_credential(self) -> OpcUaUser:
        given = [k for k in ("password", "password_env", "password_file", "certificate") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError(
                f"user '{self.name}': give exactly one of password_env, password_file, password or certificate "
                f"(got {given or 'none'})"
            )
        return self

    def secret(self, root: Path | None = None) -> str:
        """The password, read now; a relative ``password_file`` is taken from ``root`` (``serve --workdir``, as the
        certificates are), else from the current folder. Raises TokenUnavailable naming the setting, the file's
        absolute path and the fix (the API tokens' rules)."""
        if self.password is not None:
            return self.password
        path = None if self.password_file is None else ((root or Path()) / self.password_file).absolute()
        return read_secret(f"opcua.users '{self.name}'", env=("password_env", self.password_env),
                           file=("password_file", path), what="password")  # fmt: skip


class OpcUaConfig(StrictModel):
    """OPC UA server (OPC 30050 PackML model; node set: docs/opcua_nodeset.md)."""

    enabled: bool = True
    host: ListenHost = "127.0.0.1"
    port: int = Field(4840, ge=0, le=65535)  # 0: any free port (tests); the server reports the one it got
    path: str = Field("/cellctl", pattern=r"^/[A-Za-z0-9/_.-]*$")  # endpoint opc.tcp://host:port<path>
    application_uri: str = Field("urn:cellctl:{cell_id}", min_length=1)  # {cell_id} is replaced; must match the certificate
    security_policies: tuple[SecurityPolicy, ...] = ("Basic256Sha256_SignAndEncrypt",)
    allow_anonymous: bool = False
    certificate: Path = Path("var/opcua/server-cert.der")  # created on first start if absent (with private_key)
    private_key: Path = Path("var/opcua/server-key.pem")
    trusted_clients: Path | None = None  # folder of trusted client certificates; None trusts any (the simulated cell only)
    users: tuple[OpcUaUser, ...] = (OpcUaUser(name="operator", password=SIM_DEFAULT_PASSWORD),)

    @model_validator(mode="after")
    def _sane(self) -> OpcUaConfig:
        if not self.security_policies:
            raise ValueError("security_policies: give at least one, e.g. [\"Basic256Sha256_SignAndEncrypt\"]")
        check_unique("users", "name", [u.name for u in self.users])
        if not self.users and not self.allow_anonymous:
            raise ValueError("users: no user and allow_anonymous = false leaves nobody who may connect; add [[opcua.users]]")
        return self

    def rooted(self, root: Path) -> OpcUaConfig:
        """This section with its users' relative password files taken from ``root``, the folder of ``serve --workdir``,
        as its certificates are (for reading the passwords before the server starts, e.g. ``check_tokens``)."""
        base = root.resolve()
        users = tuple(u.model_copy(update={"password_file": base / u.password_file})
                      if u.password_file is not None and not u.password_file.is_absolute() else u for u in self.users)  # fmt: skip
        return self if users == self.users else self.model_copy(update={"users": users})

    def hardware_problems(self) -> list[str]:
        """What a hardware cell refuses here: anonymous access, no or sign-only security, any client certificate
        trusted, passwords in the file (field: message)."""
        if not self.enabled:
            return []
        problems = []
        if self.allow_anonymous:
            problems.append("opcua.allow_anonymous: a hardware cell refuses anonymous OPC UA sessions; set it to false "
                            "and name the plant's clients in [[opcua.users]]")
        if "None" in self.security_policies:
            problems.append('opcua.security_policies: "None" sends commands unsigned and in clear on the plant network; '
                            'use ["Basic256Sha256_SignAndEncrypt"]')
        if "Basic256Sha256_Sign" in self.security_policies:
            problems.append('opcua.security_policies: "Basic256Sha256_Sign" signs but does not encrypt, so commands, '
                            'results and part and car ids cross the plant network in clear; use '
                            '["Basic256Sha256_SignAndEncrypt"]')
        if self.trusted_clients is None:
            problems.append("opcua.trusted_clients: not set, so the server trusts every client certificate; set it to "
                            "the folder of the client certificates the cell accepts (each client's certificate as DER, "
                            'e.g. trusted_clients = "/etc/cellctl/opcua/trusted")')
        if "users" not in self.model_fields_set:
            problems.append("opcua.users: no user is configured, so the simulated cell's default password would open "
                            "the cell; add [[opcua.users]] with password_env, password_file or certificate")
        for i, u in enumerate(self.users):
            if u.password is not None:
                problems.append(f"opcua.users.{i}.password: user '{u.name}' has its password in the configuration "
                                "file; a hardware cell reads it from the environment (password_env) or a file "
                                "(password_file)")
        return problems
