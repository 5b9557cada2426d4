"""`config check --secrets` refuses what `serve` refuses at start, with serve's words: the store's folder, the MQTT
files, the OPC UA certificate's folder and a listen port another program holds; and it creates nothing."""

from __future__ import annotations

import re
import socket
from pathlib import Path

import pytest
from shared_support import LOOPBACK, free_port, run_cli

from cellctl.store.connection import StorePathError, make_store_folder

ROOT = Path(__file__).resolve().parents[2]
SIM = ROOT / "config" / "sim.toml"


def _config(tmp_path: Path, extra: str = "", **paths: str) -> tuple[Path, dict[str, int]]:
    """The simulated cell on free loopback ports, its OPC UA certificate where ``paths`` say, ``extra`` appended."""
    ports = {"api": free_port(), "plc": free_port(), "opcua": free_port()}
    text = SIM.read_text(encoding="utf-8")
    for old, new in ((r"\nport = 8080\n", f"\nport = {ports['api']}\n"), (r"\nport = 5020\n", f"\nport = {ports['plc']}\n"),
                     (r"\nport = 4840 ", f"\nport = {ports['opcua']} ")):  # fmt: skip
        text, n = re.subn(old, new, text, count=1)
        assert n == 1, old
    for key, value in paths.items():
        text, n = re.subn(rf'\n{key} = "[^"]*"', f'\n{key} = "{value}"', text, count=1)
        assert n == 1, key
    cfg = tmp_path / "cell.toml"
    cfg.write_text(text + extra, encoding="utf-8")
    return cfg, ports


def _check(capsys: pytest.CaptureFixture[str], cfg: Path, workdir: Path) -> tuple[int, str, str]:
    return run_cli(capsys, "config", "check", "--config", str(cfg), "--secrets", "--workdir", str(workdir))


def test_a_store_path_under_a_file_is_refused_with_serves_message(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "afile").write_text("x")
    cfg, _ = _config(tmp_path, '\n[store]\npath = "afile/cellctl.db"\n')
    rc, out, err = _check(capsys, cfg, tmp_path)
    with pytest.raises(StorePathError) as serve:  # what serve calls on this path (compose: make_store_folder)
        make_store_folder(tmp_path / "afile" / "cellctl.db")
    assert rc == 2 and out == "" and "Traceback" not in err, err
    assert str(serve.value) in err and "which is a file, not a folder" in err


def test_a_store_folder_serve_would_make_is_fine_and_not_made(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg, _ = _config(tmp_path, '\n[store]\npath = "new/deeper/cellctl.db"\n')
    rc, out, err = _check(capsys, cfg, tmp_path)
    assert rc == 0 and "certificate could be read" in out, err
    assert not (tmp_path / "new").exists() and not (tmp_path / "var").exists()  # a check creates nothing


def test_missing_mqtt_files_are_refused_as_serve_refuses_them(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    mqtt = '\n[mqtt]\nenabled = true\nusername = "cell"\npassword_file = "nope"\n\n[mqtt.tls]\nca_file = "missing-ca.pem"\n'
    cfg, _ = _config(tmp_path, mqtt)
    rc, out, err = _check(capsys, cfg, tmp_path)
    assert rc == 2 and "could be read" not in out + err, err
    assert (f"mqtt.password_file {tmp_path / 'nope'}: cannot be read (No such file or directory); create it with the "
            "broker password on one line") in err  # fmt: skip
    assert f"mqtt.tls.ca_file {tmp_path / 'missing-ca.pem'}: not a readable file; give the path of the PEM file" in err
    (tmp_path / "nope").write_text("Kq7-broker-pass-2026\n")  # the token rules: 16+ characters
    (tmp_path / "nope").chmod(0o600)
    (tmp_path / "missing-ca.pem").write_text("-----BEGIN CERTIFICATE-----\n")  # a file, but no certificate
    rc, out, err = _check(capsys, cfg, tmp_path)
    assert rc == 2 and f"mqtt.tls.ca_file: {tmp_path / 'missing-ca.pem'} holds no PEM certificate" in err, err
    (tmp_path / "missing-ca.pem").write_bytes(_self_signed_pem())
    rc, out, err = _check(capsys, cfg, tmp_path)
    assert rc == 0, err


def _self_signed_pem() -> bytes:
    """A CA certificate (PEM) for [mqtt.tls] ca_file."""
    import datetime as dt

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    key, now = ec.generate_private_key(ec.SECP256R1()), dt.datetime.now(dt.UTC)
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "plant CA")])
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name).public_key(key.public_key())
            .serial_number(x509.random_serial_number()).not_valid_before(now).not_valid_after(now + dt.timedelta(days=365))
            .sign(key, hashes.SHA256()))  # fmt: skip
    return cert.public_bytes(serialization.Encoding.PEM)


def test_an_opcua_certificate_folder_under_a_file_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "bfile").write_text("x")
    cfg, _ = _config(tmp_path, certificate="bfile/server-cert.der", private_key="bfile/server-key.pem")
    rc, _, err = _check(capsys, cfg, tmp_path)
    assert rc == 2 and "Errno" not in err, err
    assert (f"opcua.private_key {tmp_path / 'bfile' / 'server-key.pem'}: its folder {tmp_path / 'bfile'} cannot be "
            f"created or written ({tmp_path / 'bfile'} is a file, not a folder)") in err  # fmt: skip


@pytest.mark.parametrize("server", ["api", "plc", "opcua"])
def test_a_port_another_program_listens_on_is_refused(server: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg, ports = _config(tmp_path)
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as other:  # another program, on loopback only
        other.bind((LOOPBACK, ports[server]))
        other.listen()
        rc, _, err = _check(capsys, cfg, tmp_path)
    assert rc == 2, err
    assert f"another program listens on 127.0.0.1:{ports[server]} ([{server}] port): stop it or choose another port" in err
    assert err.count("another program listens") == 1
    rc, out, err = _check(capsys, cfg, tmp_path)  # once it has gone
    assert rc == 0 and "every listen port is free" in out, err



def test_the_running_services_own_ports_are_no_problem(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Beside the cell's running service (it holds the store's lock) its ports are its own: not a problem."""
    from cellctl.config import load_config
    from cellctl.service.store_lock import StoreLock

    cfg, ports = _config(tmp_path)
    db = Path(load_config(cfg).store.path)
    make_store_folder((tmp_path / db).resolve())
    with socket.socket() as busy:
        busy.bind((LOOPBACK, ports["api"]))
        busy.listen()
        code, _, err = _check(capsys, cfg, tmp_path)
        assert code == 2 and f"{LOOPBACK}:{ports['api']} ([api] port)" in err, err  # no service on this store
        lock = StoreLock((tmp_path / db).resolve())
        lock.acquire()  # this configuration's service runs
        try:
            code, out, err = _check(capsys, cfg, tmp_path)
        finally:
            lock.release()
    assert code == 0 and "the service of this configuration is running" in out, (out, err)
