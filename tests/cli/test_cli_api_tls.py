"""`[api] tls_cert` / `tls_key`: both or neither; `config check --secrets` reads them as `serve` will (relative paths
from --workdir, the key not readable by every user, the pair loadable by OpenSSL without a passphrase); a hardware
cell whose API listens beyond loopback without TLS gets a warning line, not a refusal."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest
from shared_support import run_cli
from tls_test_support import encrypted_copy, other_key, self_signed

from cellctl.config import ConfigError, load_config

ROOT = Path(__file__).resolve().parents[2]
SIM = ROOT / "config" / "sim.toml"
HARDWARE = ROOT / "config" / "hardware.example.toml"
CLEAR = "travel in clear; set api.tls_cert and api.tls_key, or bind api.host = \"127.0.0.1\" behind a TLS proxy"


def _sim(tmp_path: Path, api_lines: str, host: str = "127.0.0.1") -> Path:
    """config/sim.toml on port 0 everywhere (nothing to bind), ``api_lines`` added to [api], which has ``host``."""
    text = SIM.read_text(encoding="utf-8").replace('[api]                                  # REST API and dashboard\nhost = "127.0.0.1"',
                                                   f'[api]\nhost = "{host}"', 1)  # fmt: skip
    for old in ("\nport = 8080\n", "\nport = 5020\n"):
        text = text.replace(old, "\nport = 0\n", 1)
    text = text.replace("\nport = 4840 ", "\nport = 0 ", 1)
    text, n = re.subn(r"(?m)^\[api\].*$", lambda m: m.group(0) + "\n" + api_lines, text, count=1)
    assert n == 1
    cfg = tmp_path / "cell.toml"
    cfg.write_text(text, encoding="utf-8")
    return cfg


def _check(capsys: pytest.CaptureFixture[str], cfg: Path, workdir: Path, *more: str) -> tuple[int, str, str]:
    return run_cli(capsys, "config", "check", "--config", str(cfg), "--workdir", str(workdir), *more)


RELATIVE = 'tls_cert = "tls/api-cert.pem"\ntls_key = "tls/api-key.pem"'


@pytest.fixture()
def workdir(tmp_path: Path) -> Path:
    """A workdir holding tls/api-cert.pem and tls/api-key.pem (the tests run from another folder)."""
    (tmp_path / "tls").mkdir()
    self_signed(tmp_path / "tls")
    assert Path.cwd() != tmp_path
    return tmp_path


@pytest.mark.parametrize("given", ["tls_cert", "tls_key"])
def test_one_of_the_pair_alone_is_refused_naming_both(given: str, tmp_path: Path) -> None:
    cfg = _sim(tmp_path, f'{given} = "/etc/cellctl/x.pem"')
    with pytest.raises(ConfigError) as err:
        load_config(cfg)
    missing = "tls_key" if given == "tls_cert" else "tls_cert"
    assert f"{given} is set but {missing} is not" in str(err.value) and "or neither" in str(err.value), err.value


def test_relative_tls_files_are_read_from_the_workdir(workdir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc, out, err = _check(capsys, _sim(workdir, RELATIVE), workdir, "--secrets")
    assert rc == 0 and "REST API and dashboard  https://127.0.0.1:0/" in out and "API TLS files" in out, err


@pytest.mark.parametrize(
    ("damage", "said"),
    [
        ("world-readable key", "api.tls_key: {key} can be read or written by every user (mode 0644); chmod 600 {key}"),
        ("missing certificate", "api.tls_cert: {cert} cannot be read (No such file or directory)"),
        ("another key", "api.tls_key: {key} is not the private key of api.tls_cert {cert}; give the certificate's own key"),
        ("encrypted key", "api.tls_key: {key} is encrypted with a passphrase"),
        ("not PEM", "api.tls_cert, api.tls_key: {cert} and {key} are not a PEM certificate and its unencrypted PEM"),
    ],
)
def test_an_unusable_tls_file_is_refused_naming_its_field_and_absolute_path(
    damage: str, said: str, workdir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cert, key = workdir / "tls" / "api-cert.pem", workdir / "tls" / "api-key.pem"
    if damage == "world-readable key":
        os.chmod(key, 0o644)
    elif damage == "missing certificate":
        cert.unlink()
    elif damage == "another key":
        other_key(key)
    elif damage == "encrypted key":
        encrypted_copy(key, b"a passphrase")  # OpenSSL would prompt on the terminal: refused instead
    else:
        cert.write_text("not a certificate\n")
    rc, out, err = _check(capsys, _sim(workdir, RELATIVE), workdir, "--secrets")
    assert rc == 2 and out == "" and "Traceback" not in err, err
    assert said.format(cert=cert, key=key) in err, err


def _hardware(tmp_path: Path, host: str | None = None, tls: bool = False) -> Path:
    """config/hardware.example.toml (loaded, never served), its [api] host replaced or TLS files named."""
    text = HARDWARE.read_text(encoding="utf-8")
    api = text.index("\n[api]\n")
    head, tail = text[:api], text[api:]
    if host is not None:
        tail = tail.replace('host = "0.0.0.0"', f'host = "{host}"', 1)
    if tls:
        tail = tail.replace("# tls_cert = ", "tls_cert = ", 1).replace("# tls_key = ", "tls_key = ", 1)
    cfg = tmp_path / "cell.toml"
    cfg.write_text(head + tail, encoding="utf-8")
    return cfg


def test_a_hardware_api_on_the_network_without_tls_is_warned_not_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rc, out, err = _check(capsys, _hardware(tmp_path), tmp_path)  # the shipped example: 0.0.0.0, no TLS
    warning = [line for line in out.splitlines() if line.startswith("warning: ")]
    assert rc == 0 and len(warning) == 1, out + err
    assert warning[0] == f"warning: api.host = '0.0.0.0' is reached from the network over plain HTTP: the bearer " \
                         f"tokens (the engineer's too) {CLEAR}"


@pytest.mark.parametrize("case", ["loopback", "tls", "simulated cell"])
def test_no_warning_on_loopback_with_tls_or_in_the_simulated_cell(
    case: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    if case == "simulated cell":
        cfg = _sim(tmp_path, "", host="0.0.0.0")  # loaded only: config check binds nothing on port 0
        assert load_config(cfg).api.host == "0.0.0.0"
    else:
        cfg = _hardware(tmp_path, host="127.0.0.1" if case == "loopback" else None, tls=case == "tls")
    rc, out, err = _check(capsys, cfg, tmp_path)
    assert rc == 0 and "warning:" not in out + err and "travel in clear" not in out + err, out + err
