"""The cell's MQTT TLS client key ([mqtt.tls] key_file) is kept as the password file is: one that every user may
read or write is refused at start and by `config check --secrets`, naming the field and the chmod; at 0600 it is
handed to TLS, and Python's ssl loads it with its certificate."""

from __future__ import annotations

import datetime as dt
import os
import ssl
import stat
from pathlib import Path

import pytest
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID
from shared_support import free_port, run_cli

from cellctl.config.mqtt import MqttConfig, MqttTls
from cellctl.mqtt.publication import MqttSetupError, tls_parameters

SIM = Path(__file__).resolve().parents[2] / "config" / "sim.toml"


def _client_pair(folder: Path) -> tuple[Path, Path]:
    """A self-signed client certificate and its key, PEM, as the plant's CA would issue them."""
    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "glazing-1")])
    now = dt.datetime.now(dt.UTC)
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name).public_key(key.public_key())
            .serial_number(x509.random_serial_number()).not_valid_before(now).not_valid_after(now + dt.timedelta(days=1))
            .sign(key, hashes.SHA256()))  # fmt: skip
    cert_path, key_path = folder / "cell.pem", folder / "cell.key"
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    key_path.write_bytes(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                           serialization.NoEncryption()))  # fmt: skip
    return cert_path, key_path


def _config(cert: Path, key: Path) -> MqttConfig:
    return MqttConfig(enabled=True, tls=MqttTls(ca_file=cert, cert_file=cert, key_file=key))


@pytest.mark.parametrize("mode", [0o644, 0o604, 0o602], ids=["0644", "0604", "0602"])
def test_a_client_key_every_user_may_read_or_write_is_refused(tmp_path: Path, mode: int) -> None:
    cert, key = _client_pair(tmp_path)
    os.chmod(key, mode)
    assert stat.S_IMODE(key.stat().st_mode) == mode
    with pytest.raises(MqttSetupError) as err:
        tls_parameters(_config(cert, key), tmp_path)
    assert str(err.value).startswith(f"mqtt.tls.key_file: {key} can be read or written by every user (mode {mode:04o}); "
                                     f"chmod 600 {key}"), err.value  # fmt: skip


def test_a_client_key_of_the_service_alone_is_handed_to_tls(tmp_path: Path) -> None:
    cert, key = _client_pair(tmp_path)
    os.chmod(cert, 0o644)  # a certificate is public: only the key is held to the rule
    for mode in (0o600, 0o640):
        os.chmod(key, mode)
        params = tls_parameters(_config(cert, key), tmp_path)
        assert params is not None and params.keyfile == str(key) and params.certfile == str(cert)
        ssl.create_default_context().load_cert_chain(params.certfile, params.keyfile)  # a key TLS can use


def test_config_check_names_a_world_readable_client_key(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cert, key = _client_pair(tmp_path)
    os.chmod(key, 0o644)
    text = SIM.read_text(encoding="utf-8")
    for default in ("\nport = 8080\n", "\nport = 5020\n", "\nport = 4840 "):
        assert text.count(default) == 1
        text = text.replace(default, default.replace(default.split()[-1], str(free_port())), 1)
    text += (f'\n[mqtt]\nenabled = true\nhost = "127.0.0.1"\nport = {free_port()}\n'
             f'[mqtt.tls]\nca_file = "{cert}"\ncert_file = "{cert}"\nkey_file = "{key}"\n')  # fmt: skip
    cfg = tmp_path / "cell.toml"
    cfg.write_text(text, encoding="utf-8")
    rc, out, err = run_cli(capsys, "config", "check", "--config", str(cfg), "--secrets", "--workdir", str(tmp_path))
    assert rc == 2 and f"mqtt.tls.key_file: {key} can be read or written by every user (mode 0644)" in err, out + err
    os.chmod(key, 0o600)
    rc, out, err = run_cli(capsys, "config", "check", "--config", str(cfg), "--secrets", "--workdir", str(tmp_path))
    assert rc == 0 and "(TLS)" in out, out + err
