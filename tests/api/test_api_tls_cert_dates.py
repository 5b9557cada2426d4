"""`[api] tls_cert` outside its validity (expired, not yet valid) is refused by `config check --secrets` and by
`serve` (exit 2), naming the setting and the dates; one that expires within 30 days is warned about; a chain with the
CA first is named as misordered, not as the wrong key. The peers: Python's ssl client, which refuses the same
certificate once a server presents it (so the check says what every client will find), and OpenSSL's
load_cert_chain, which takes the same key with the chain in the right order. Dates are relative to the OS clock."""

from __future__ import annotations

import datetime
import re
import subprocess
import sys
from pathlib import Path

import pytest
from service_test_support import ROOT, free_port
from shared_support import run_cli
from tls_dates_support import NOW, issue, tls_server, utc, verify_failure

pytestmark = pytest.mark.timeout(120)
DAY = datetime.timedelta(days=1)
SIM = ROOT / "config" / "sim.toml"
EXPIRED_CODE, NOT_YET_VALID_CODE = 10, 9  # OpenSSL's X509_V_ERR_CERT_HAS_EXPIRED, X509_V_ERR_CERT_NOT_YET_VALID


def _config(folder: Path, pki: dict[str, Path], api_port: int = 0) -> Path:
    """config/sim.toml on port 0 (the API on ``api_port``) serving HTTPS with ``pki``'s chain and key."""
    text = SIM.read_text(encoding="utf-8").replace("\nport = 8080\n", f"\nport = {api_port}\n", 1)
    text = text.replace("\nport = 5020\n", "\nport = 0\n", 1)
    text = text.replace("\nport = 4840 ", "\nport = 0 ", 1)
    text, n = re.subn(r"(?m)^\[api\].*$", lambda m: f'{m.group(0)}\ntls_cert = "{pki["chain"]}"\ntls_key = "{pki["key"]}"',
                      text, count=1)  # fmt: skip
    assert n == 1
    cfg = folder / "cell.toml"
    cfg.write_text(text, encoding="utf-8")
    return cfg


def _check(capsys: pytest.CaptureFixture[str], cfg: Path, workdir: Path) -> tuple[int, str, str]:
    return run_cli(capsys, "config", "check", "--config", str(cfg), "--secrets", "--workdir", str(workdir))


@pytest.mark.parametrize(
    ("case", "start", "end", "code", "said"),
    [
        ("expired", NOW - 400 * DAY, NOW - 35 * DAY, EXPIRED_CODE, "has expired"),
        ("not yet valid", NOW + 30 * DAY, NOW + 400 * DAY, NOT_YET_VALID_CODE, "is not valid yet"),
    ],
)
def test_a_certificate_outside_its_dates_is_refused_with_them(
    case: str, start: datetime.datetime, end: datetime.datetime, code: int, said: str,
    tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    pki = issue(tmp_path, "cell", start, end)
    with tls_server(pki["chain"], pki["key"]) as port:  # what a client will find: refused, whatever CA it is given
        assert verify_failure(port, pki["ca"]).verify_code == code
    rc, out, err = _check(capsys, _config(tmp_path, pki), tmp_path)
    assert rc == 2 and "Traceback" not in err, out + err
    line = f"api.tls_cert: {pki['chain']} {said} (valid from {utc(start)} to {utc(end)}; now "
    assert line in err and "have the plant's CA issue a new one" in err, err
    cfg = _config(tmp_path, pki, api_port=free_port())  # serve refuses before it binds anything
    done = subprocess.run([sys.executable, "-m", "cellctl.cli", "--config", str(cfg), "serve",
                           "--workdir", str(tmp_path)], capture_output=True, text=True, timeout=90, cwd=ROOT)  # fmt: skip
    # not valid yet: the clock stands behind, a restart once it is synced helps (exit 1, restarted); expired: exit 2
    assert done.returncode == (1 if case == "not yet valid" else 2) and "Traceback" not in done.stderr, done.stderr
    assert f"error: the REST API cannot serve HTTPS: {line}" in done.stderr and "cellctl serving" not in done.stdout


def test_a_certificate_expiring_within_30_days_is_warned_not_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    end = NOW + 10 * DAY + datetime.timedelta(hours=1)
    pki = issue(tmp_path, "cell", NOW - 355 * DAY, end)
    rc, out, err = _check(capsys, _config(tmp_path, pki), tmp_path)
    assert rc == 0 and out.startswith("OK: "), out + err
    assert f"api.tls_cert: {pki['chain']} expires in 10 day(s), on {utc(end)}" in err, err
    far = issue(tmp_path, "far", NOW - DAY, NOW + 90 * DAY)
    rc, out, err = _check(capsys, _config(tmp_path, far), tmp_path)
    assert rc == 0 and "expires in" not in err, out + err


def test_a_chain_with_the_ca_first_is_named_as_misordered(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import ssl

    pki = issue(tmp_path, "cell", NOW - DAY, NOW + 90 * DAY, ca_first=True)
    with pytest.raises(ssl.SSLError, match="KEY_VALUES_MISMATCH"):  # OpenSSL takes the first certificate as the leaf
        ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER).load_cert_chain(pki["chain"], pki["key"])
    blocks = re.findall(rb"-----BEGIN CERTIFICATE-----.+?-----END CERTIFICATE-----\n", pki["chain"].read_bytes(), re.S)
    (tmp_path / "ordered.pem").write_bytes(blocks[1] + blocks[0])
    ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER).load_cert_chain(tmp_path / "ordered.pem", pki["key"])  # the key is right
    rc, out, err = _check(capsys, _config(tmp_path, pki), tmp_path)
    assert rc == 2 and "is not the private key" not in err, err
    assert (f"api.tls_cert: {pki['chain']} is in the wrong order: the certificate of api.tls_key {pki['key']} is "
            "certificate 2 in it; the server's certificate must come first in api.tls_cert, the intermediate CA "
            "certificates after it") in err, err
    other = issue(tmp_path, "other", NOW - DAY, NOW + 90 * DAY)  # a key of no certificate in the file: as before
    pki["key"].write_bytes(other["key"].read_bytes())
    rc, out, err = _check(capsys, _config(tmp_path, pki), tmp_path)
    assert rc == 2 and f"api.tls_key: {pki['key']} is not the private key of api.tls_cert {pki['chain']}" in err, err
