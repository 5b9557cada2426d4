"""The [mqtt.tls] files are loaded when the service starts as the TLS client loads them at connect, so a file TLS
cannot use stops `serve` (exit 2) and `config check --secrets` naming the field, instead of a broker retried forever:
a ca_file that holds no certificate, a key_file that is not cert_file's key (or has a passphrase), a cert_file whose
chain has the CA first, and a client certificate outside its validity (refused with its dates).

Judged by Python's ssl (OpenSSL) loading the same files, by a real mosquitto that asks for a client certificate
(it accepts the pair the cell accepts and refuses the expired one), and by the dates written into the certificates."""

from __future__ import annotations

import datetime as dt
import os
import pwd
import shutil
import ssl
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import aiomqtt
import pytest
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID
from mosquitto_support import Broker
from service_test_support import sim_toml
from shared_support import LOOPBACK, free_port, run_cli

from cellctl.config.mqtt import MqttConfig, MqttTls
from cellctl.mqtt.publication import MqttSetupError, tls_parameters

pytestmark = pytest.mark.timeout(240)
DAY = dt.timedelta(days=1)
STAMP = "%Y-%m-%d %H:%M"


def _pem(cert: x509.Certificate) -> bytes:
    return cert.public_bytes(serialization.Encoding.PEM)


def _key_pem(key: ec.EllipticCurvePrivateKey, password: bytes | None = None) -> bytes:
    enc = serialization.BestAvailableEncryption(password) if password else serialization.NoEncryption()
    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, enc)


class Pki:
    """A plant CA of the test's own; it issues the broker's certificate (127.0.0.1) and client certificates."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.key = ec.generate_private_key(ec.SECP256R1())
        self.name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "plant CA")])
        now = dt.datetime.now(dt.UTC)
        self.cert = (x509.CertificateBuilder().subject_name(self.name).issuer_name(self.name)
                     .public_key(self.key.public_key()).serial_number(x509.random_serial_number())
                     .not_valid_before(now - DAY).not_valid_after(now + 365 * DAY)
                     .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
                     .sign(self.key, hashes.SHA256()))  # fmt: skip
        self.ca_file = self.write("ca.pem", _pem(self.cert))

    def write(self, name: str, data: bytes, mode: int = 0o600) -> Path:
        path = self.folder / name
        path.write_bytes(data)
        os.chmod(path, mode)
        return path

    def issue(self, name: str, start: dt.datetime, end: dt.datetime, *, server: bool = False) -> tuple[x509.Certificate, Path, Path]:
        """A certificate valid from ``start`` to ``end`` (UTC) and its key: (certificate, cert file, key file)."""
        key = ec.generate_private_key(ec.SECP256R1())
        builder = (x509.CertificateBuilder().subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)]))
                   .issuer_name(self.name).public_key(key.public_key()).serial_number(x509.random_serial_number())
                   .not_valid_before(start).not_valid_after(end))  # fmt: skip
        if server:
            import ipaddress

            builder = builder.add_extension(x509.SubjectAlternativeName([x509.IPAddress(ipaddress.ip_address(LOOPBACK))]),
                                            critical=False)  # fmt: skip
        cert = builder.sign(self.key, hashes.SHA256())
        return cert, self.write(f"{name}.pem", _pem(cert), 0o644), self.write(f"{name}.key", _key_pem(key))

    def client(self, name: str = "glazing-1", start_days: float = -1, end_days: float = 90) -> tuple[x509.Certificate, Path, Path]:
        now = dt.datetime.now(dt.UTC)
        return self.issue(name, now + start_days * DAY, now + end_days * DAY)


def _config(ca: Path, cert: Path | None = None, key: Path | None = None) -> MqttConfig:
    return MqttConfig(enabled=True, tls=MqttTls(ca_file=ca, cert_file=cert, key_file=key))


def _refusal(config: MqttConfig, workdir: Path) -> str:
    with pytest.raises(MqttSetupError) as err:
        tls_parameters(config, workdir)
    return str(err.value)


@pytest.fixture
def pki(tmp_path: Path) -> Pki:
    return Pki(tmp_path)


@pytest.mark.parametrize("content", ["text", "truncated", "private_key", "der"])
def test_a_ca_file_that_holds_no_certificate_is_refused_naming_it(pki: Pki, content: str) -> None:
    data = {"text": b"this is the plant's CA, promise\n", "truncated": b"-----BEGIN CERTIFICATE-----\n",
            "private_key": _key_pem(pki.key), "der": pki.cert.public_bytes(serialization.Encoding.DER)}[content]  # fmt: skip
    ca = pki.write("bad-ca.pem", data, 0o644)
    with pytest.raises(ssl.SSLError):  # what the TLS client would meet at each connect
        ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT).load_verify_locations(cafile=str(ca))
    message = _refusal(_config(ca), pki.folder)
    assert message.startswith(f"mqtt.tls.ca_file: {ca} holds no PEM certificate OpenSSL can load ("), message
    assert message.endswith("give the PEM certificate of the CA that signed the broker's certificate"), message


def test_a_client_key_of_another_certificate_is_refused_naming_key_file(pki: Pki) -> None:
    _, cert, _ = pki.client("glazing-1")
    _, _, other_key = pki.client("glazing-2")
    with pytest.raises(ssl.SSLError) as peer:
        ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT).load_cert_chain(str(cert), str(other_key))
    assert peer.value.reason == "KEY_VALUES_MISMATCH"
    assert _refusal(_config(pki.ca_file, cert, other_key), pki.folder) == (
        f"mqtt.tls.key_file: {other_key} is not the private key of mqtt.tls.cert_file {cert}; give the certificate's own key")


def test_a_chain_with_the_ca_first_is_named_as_such(pki: Pki) -> None:
    client, _, key = pki.client()
    chain = pki.write("wrong-order.pem", _pem(pki.cert) + _pem(client), 0o644)
    message = _refusal(_config(pki.ca_file, chain, key), pki.folder)
    assert message.startswith(f"mqtt.tls.cert_file: {chain} holds the certificate of mqtt.tls.key_file {key}, but not "
                              "first; put the client's own certificate first"), message  # fmt: skip
    right = pki.write("right-order.pem", _pem(client) + _pem(pki.cert), 0o644)
    assert tls_parameters(_config(pki.ca_file, right, key), pki.folder) is not None


def test_a_client_key_with_a_passphrase_is_refused_without_asking(pki: Pki) -> None:
    _, cert, key = pki.client()
    encrypted = pki.write("encrypted.key", _key_pem(ec.generate_private_key(ec.SECP256R1()), b"secret-pass"))
    serialization.load_pem_private_key(encrypted.read_bytes(), b"secret-pass")  # it is an encrypted key
    message = _refusal(_config(pki.ca_file, cert, encrypted), pki.folder)
    assert message.startswith(f"mqtt.tls.key_file: {encrypted} is encrypted with a passphrase"), message
    assert tls_parameters(_config(pki.ca_file, cert, key), pki.folder) is not None


def test_files_that_are_not_a_certificate_or_a_key_name_their_field(pki: Pki) -> None:
    _, cert, key = pki.client()
    assert _refusal(_config(pki.ca_file, key, key), pki.folder).startswith(f"mqtt.tls.cert_file: {key} is not a PEM certificate")
    as_key = pki.write("cert-as-key.pem", cert.read_bytes())  # 0600: held to the key's rule, then read as a key
    assert _refusal(_config(pki.ca_file, cert, as_key), pki.folder).startswith(f"mqtt.tls.key_file: {as_key} is not a PEM private key")


@pytest.mark.parametrize(("start_days", "end_days", "words"), [(-40, -5, "has expired"), (5, 40, "is not valid yet")],
                         ids=["expired", "not_yet_valid"])  # fmt: skip
def test_a_client_certificate_outside_its_validity_is_refused_with_its_dates(
    pki: Pki, start_days: float, end_days: float, words: str
) -> None:
    client, cert, key = pki.client(start_days=start_days, end_days=end_days)
    start, end = client.not_valid_before_utc.strftime(STAMP), client.not_valid_after_utc.strftime(STAMP)
    message = _refusal(_config(pki.ca_file, cert, key), pki.folder)
    assert message.startswith(f"mqtt.tls.cert_file: {cert} {words} (valid from {start} UTC to {end} UTC; now "), message
    assert "so the broker refuses it: " in message and "have the plant's CA issue a new client certificate" in message


def test_a_client_certificate_close_to_its_end_is_used_with_a_warning(pki: Pki, caplog: pytest.LogCaptureFixture) -> None:
    client, cert, key = pki.client(start_days=-300, end_days=10.5)
    with caplog.at_level("WARNING", logger="cellctl.mqtt.publication"):
        assert tls_parameters(_config(pki.ca_file, cert, key), pki.folder) is not None
    end = client.not_valid_after_utc.strftime(STAMP)
    assert [r.getMessage() for r in caplog.records] == [
        f"mqtt.tls.cert_file: {cert} expires in 10 day(s), on {end} UTC; then the broker refuses it: have the plant's "
        "CA issue a new client certificate, and restart the service before then"]
    caplog.clear()
    _, cert, key = pki.client("glazing-2", start_days=-300, end_days=60)
    with caplog.at_level("WARNING", logger="cellctl.mqtt.publication"):
        assert tls_parameters(_config(pki.ca_file, cert, key), pki.folder) is not None
    assert caplog.records == []


@pytest.fixture
def tls_broker(pki: Pki) -> Iterator[Broker]:
    """mosquitto with one TLS listener on loopback that asks every client for a certificate of ``pki``'s CA."""
    _, server_cert, server_key = pki.issue("broker", dt.datetime.now(dt.UTC) - DAY, dt.datetime.now(dt.UTC) + 30 * DAY, server=True)
    files = Path(tempfile.mkdtemp(prefix="cellctl-mosquitto-tls-"))  # mosquitto drops to its own user when run as root
    for path in (files, *(Path(shutil.copy(f, files / f.name)) for f in (pki.ca_file, server_cert, server_key))):
        if os.geteuid() == 0:
            user = pwd.getpwnam("mosquitto")
            os.chown(path, user.pw_uid, user.pw_gid)
    broker = Broker(pki.folder)
    broker.conf.write_text(
        f"listener {broker.port} {LOOPBACK}\nallow_anonymous true\ncafile {files / pki.ca_file.name}\n"
        f"certfile {files / server_cert.name}\nkeyfile {files / server_key.name}\nrequire_certificate true\n"
        "log_dest stderr\nlog_type all\n"
    )  # fmt: skip
    broker.start()
    try:
        yield broker
    finally:
        broker.close()
        shutil.rmtree(files, ignore_errors=True)


async def _connects(port: int, params: aiomqtt.TLSParameters) -> None:
    async with aiomqtt.Client(LOOPBACK, port, identifier="tls-test", tls_params=params, timeout=5):
        pass


async def test_the_broker_accepts_what_the_cell_accepts_and_refuses_the_expired_client(pki: Pki, tls_broker: Broker) -> None:
    _, cert, key = pki.client()
    params = tls_parameters(_config(pki.ca_file, cert, key), pki.folder)
    assert params is not None
    await _connects(tls_broker.port, params)  # the broker takes this pair

    _, old_cert, old_key = pki.client("glazing-old", start_days=-40, end_days=-5)
    with pytest.raises(aiomqtt.MqttError):  # the broker refuses the expired certificate at the handshake
        await _connects(tls_broker.port, aiomqtt.TLSParameters(ca_certs=str(pki.ca_file), certfile=str(old_cert), keyfile=str(old_key)))
    assert "certificate verify failed" in tls_broker.log.read_text()
    assert _refusal(_config(pki.ca_file, old_cert, old_key), pki.folder).startswith(f"mqtt.tls.cert_file: {old_cert} has expired")


def _cell_toml(tmp_path: Path, tls: str) -> Path:
    """The simulated cell (REST on a free port, PLC and OPC UA off) publishing over TLS to a loopback port."""
    cfg = tmp_path / "cell.toml"
    cfg.write_text(sim_toml(free_port()) + f'\n[mqtt]\nenabled = true\nhost = "{LOOPBACK}"\nport = {free_port()}\n\n[mqtt.tls]\n{tls}\n',
                   encoding="utf-8")  # fmt: skip
    return cfg


def test_config_check_secrets_names_the_unusable_tls_files(pki: Pki, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    garbage = pki.write("garbage.pem", b"not a certificate\n", 0o644)
    _, cert, _ = pki.client("glazing-1")
    _, _, other_key = pki.client("glazing-2")
    cfg = _cell_toml(tmp_path, f'ca_file = "{garbage}"\ncert_file = "{cert}"\nkey_file = "{other_key}"')
    rc, out, err = run_cli(capsys, "config", "check", "--config", str(cfg), "--secrets", "--workdir", str(tmp_path))
    assert rc == 2 and out == "", out + err
    assert f"mqtt.tls.ca_file: {garbage} holds no PEM certificate" in err, err
    cfg = _cell_toml(tmp_path, f'ca_file = "{pki.ca_file}"\ncert_file = "{cert}"\nkey_file = "{other_key}"')
    rc, out, err = run_cli(capsys, "config", "check", "--config", str(cfg), "--secrets", "--workdir", str(tmp_path))
    assert rc == 2 and f"mqtt.tls.key_file: {other_key} is not the private key of mqtt.tls.cert_file {cert}" in err, err
    _, old_cert, old_key = pki.client("glazing-old", start_days=-40, end_days=-5)
    cfg = _cell_toml(tmp_path, f'ca_file = "{pki.ca_file}"\ncert_file = "{old_cert}"\nkey_file = "{old_key}"')
    rc, out, err = run_cli(capsys, "config", "check", "--config", str(cfg), "--secrets", "--workdir", str(tmp_path))
    assert rc == 2 and f"mqtt.tls.cert_file: {old_cert} has expired" in err, err


def test_serve_stops_with_exit_2_naming_a_ca_file_without_a_certificate(pki: Pki, tmp_path: Path) -> None:
    import subprocess

    garbage = pki.write("garbage.pem", b"not a certificate\n", 0o644)
    cfg = _cell_toml(tmp_path, f'ca_file = "{garbage}"')
    env = {k: v for k, v in os.environ.items() if not k.startswith("CELLCTL_")}
    try:
        done = subprocess.run([sys.executable, "-m", "cellctl", "--config", str(cfg), "serve", "--workdir", str(tmp_path)],
                              capture_output=True, text=True, timeout=120, env=env)  # fmt: skip
    except subprocess.TimeoutExpired:
        pytest.fail("serve kept running with an mqtt.tls.ca_file that holds no certificate")
    assert done.returncode == 2, done.stderr[-2000:]
    assert f"mqtt.tls.ca_file: {garbage} holds no PEM certificate" in done.stderr, done.stderr[-2000:]
