"""A cell PC whose clock stands behind at start (booted before NTP set it, a flat RTC battery, or a step back just after
the first start) does not stay down once the clock is right: the OPC UA certificate the service made is valid from a
day before it was made, and a certificate that is not valid yet by the clock (OPC UA, MQTT) ends `serve` with a status
deploy/cellctl.service restarts (exit 1), not the "restart cannot help" status 2.

The real `cellctl serve` runs in a subprocess with its wall clock stepped in-process (clock_step_support, monotonic
untouched). Scored against the OS: the process's exit status, read against the unit's Restart= and
RestartPreventExitStatus=, and httpx on the REST port; the certificate file's bytes."""

from __future__ import annotations

import datetime as dt
import os
import signal
import subprocess
import sys
from pathlib import Path

import httpx
import pytest
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID
from service_test_support import ROOT, sim_toml
from shared_support import LOOPBACK, free_port

import clock_step_support

pytestmark = pytest.mark.timeout(240)
STEPPED = Path(clock_step_support.__file__)
UNIT = ROOT / "deploy" / "cellctl.service"
DAY = dt.timedelta(days=1)


def _unit_restarts(status: int) -> bool:
    """Whether deploy/cellctl.service starts the service again after it exits with ``status`` (Restart=on-failure)."""
    settings = dict(line.split("=", 1) for line in UNIT.read_text().splitlines() if "=" in line and line[:1].isalpha())
    return status != 0 and settings["Restart"] == "on-failure" and str(status) not in settings["RestartPreventExitStatus"].split()


def _opcua_cell(tmp_path: Path) -> tuple[Path, str]:
    """config/sim.toml with OPC UA on (port 0; its certificate made under the workdir), PLC off: (config, REST URL)."""
    port = free_port()
    text = sim_toml(port).replace("[opcua]\nenabled = false", "[opcua]\nenabled = true", 1).replace("\nport = 4840 ", "\nport = 0 ", 1)
    cfg = tmp_path / "cell.toml"
    cfg.write_text(text, encoding="utf-8")
    return cfg, f"http://{LOOPBACK}:{port}"


def _serve(cfg: Path, workdir: Path, offset_s: float) -> subprocess.Popen[bytes]:
    """`cellctl serve` with its wall clock ``offset_s`` off (negative: behind); output in workdir/serve<offset>.log."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("CELLCTL_")} | {clock_step_support.OFFSET_ENV: str(offset_s)}
    with open(workdir / f"serve{offset_s:+.0f}.log", "ab") as log:
        return subprocess.Popen([sys.executable, str(STEPPED), "--config", str(cfg), "serve", "--workdir", str(workdir)],
                                stdout=log, stderr=log, env=env, cwd=workdir)  # fmt: skip


def _up(proc: subprocess.Popen[bytes], url: str, deadline_s: float = 90.0) -> bool:
    """Until GET /status answers 200 (True) or the process ends or the deadline passes (False)."""
    import time

    end = time.monotonic() + deadline_s
    with httpx.Client(timeout=2) as http:  # one client: a new one per try loads the CA bundle each time
        while time.monotonic() < end and proc.poll() is None:
            try:
                if http.get(f"{url}/status").status_code == 200:
                    return True
            except httpx.HTTPError:
                pass
            time.sleep(0.2)
    return False


def _stop(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def _start_once(cfg: Path, workdir: Path, url: str, offset_s: float) -> None:
    proc = _serve(cfg, workdir, offset_s)
    try:
        assert _up(proc, url), (workdir / f"serve{offset_s:+.0f}.log").read_text()[-3000:]
    finally:
        _stop(proc)


def test_a_clock_stepped_back_30_s_after_the_first_start_does_not_refuse_the_made_certificate(tmp_path: Path) -> None:
    cfg, url = _opcua_cell(tmp_path)
    _start_once(cfg, tmp_path, url, 0.0)  # the first start makes var/opcua/server-cert.der
    cert = tmp_path / "var" / "opcua" / "server-cert.der"
    made = cert.read_bytes()
    start = x509.load_der_x509_certificate(made).not_valid_before_utc
    assert start <= dt.datetime.now(dt.timezone.utc) - DAY + dt.timedelta(minutes=1), start  # back-dated a day
    _start_once(cfg, tmp_path, url, -30.0)  # chrony's makestep just after the first start: it comes up
    assert cert.read_bytes() == made  # kept, not made again


def test_a_boot_400_days_behind_exits_with_a_status_the_unit_restarts_and_starts_once_the_clock_is_right(
    tmp_path: Path,
) -> None:
    cfg, url = _opcua_cell(tmp_path)
    _start_once(cfg, tmp_path, url, 0.0)
    cert = tmp_path / "var" / "opcua" / "server-cert.der"
    made = cert.read_bytes()
    behind = -400 * 86400.0  # a flat RTC battery: the BIOS date
    proc = _serve(cfg, tmp_path, behind)
    try:
        up = _up(proc, url, 60.0)
        status = proc.wait(30)
    finally:
        _stop(proc)
    said = (tmp_path / f"serve{behind:+.0f}.log").read_text()
    assert not up and status == 1 and _unit_restarts(status), (status, said[-3000:])
    assert f"opcua.certificate {cert} is not valid yet" in said and "clock stands behind" in said, said[-3000:]
    assert "restarts the service" in said or "starts the service again" in said, said[-3000:]
    assert "Traceback" not in said, said[-3000:]
    _start_once(cfg, tmp_path, url, 0.0)  # NTP has set the clock: the restart comes up, with the same certificate
    assert cert.read_bytes() == made


def _mqtt_client_certificate(folder: Path, start: dt.datetime, end: dt.datetime) -> tuple[Path, Path, Path]:
    """A plant CA and a client certificate it signed, valid ``start``-``end``: (ca file, cert file, key file)."""
    ca_key, key = ec.generate_private_key(ec.SECP256R1()), ec.generate_private_key(ec.SECP256R1())
    ca_name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "plant CA")])
    now = dt.datetime.now(dt.timezone.utc)
    ca = (x509.CertificateBuilder().subject_name(ca_name).issuer_name(ca_name).public_key(ca_key.public_key())
          .serial_number(x509.random_serial_number()).not_valid_before(now - 365 * DAY).not_valid_after(now + 365 * DAY)
          .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True).sign(ca_key, hashes.SHA256()))  # fmt: skip
    leaf = (x509.CertificateBuilder().subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "glazing-1")]))
            .issuer_name(ca_name).public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(start).not_valid_after(end).sign(ca_key, hashes.SHA256()))  # fmt: skip
    pem = serialization.Encoding.PEM
    files = folder / "ca.pem", folder / f"client-{start:%Y%m%d}.pem", folder / f"client-{start:%Y%m%d}.key"
    files[0].write_bytes(ca.public_bytes(pem))
    files[1].write_bytes(leaf.public_bytes(pem))
    files[2].write_bytes(key.private_bytes(pem, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()))
    os.chmod(files[2], 0o600)
    return files


@pytest.mark.parametrize(("start_days", "end_days", "status", "words"), [(5, 40, 1, "is not valid yet"), (-40, -5, 2, "has expired")],
                         ids=["not_yet_valid", "expired"])  # fmt: skip
def test_an_mqtt_client_certificate_not_valid_yet_is_restarted_an_expired_one_is_not(
    tmp_path: Path, start_days: float, end_days: float, status: int, words: str
) -> None:
    now = dt.datetime.now(dt.timezone.utc)
    ca, cert, key = _mqtt_client_certificate(tmp_path, now + start_days * DAY, now + end_days * DAY)
    cfg = tmp_path / "cell.toml"  # no broker: the files are checked before any connection
    cfg.write_text(sim_toml(free_port()) + f'\n[mqtt]\nenabled = true\nhost = "{LOOPBACK}"\nport = {free_port()}\n\n'
                   f'[mqtt.tls]\nca_file = "{ca}"\ncert_file = "{cert}"\nkey_file = "{key}"\n', encoding="utf-8")  # fmt: skip
    env = {k: v for k, v in os.environ.items() if not k.startswith("CELLCTL_")}
    done = subprocess.run([sys.executable, "-m", "cellctl", "--config", str(cfg), "serve", "--workdir", str(tmp_path)],
                          capture_output=True, text=True, timeout=120, env=env, cwd=tmp_path)  # fmt: skip
    assert done.returncode == status and _unit_restarts(status) == (status == 1), (done.returncode, done.stderr[-2000:])
    assert f"MQTT publication cannot start: mqtt.tls.cert_file: {cert} {words}" in done.stderr, done.stderr[-2000:]
    assert ("clock stands behind" in done.stderr) == (status == 1) and "Traceback" not in done.stderr, done.stderr[-2000:]
