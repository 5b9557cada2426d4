"""When the service's HTTPS certificate is refused, the CLI's hint matches the reason Python's ssl client finds:
expired, not yet valid, issued for another name, or signed by a CA the client does not trust (only then "give
--ca"); with a token the message carries OpenSSL's reason, never the request. The peers: a TLS server of Python's
ssl module serving certificates dated against the OS clock, and Python's ssl client checking the same server."""

from __future__ import annotations

import datetime
from pathlib import Path

import pytest
from service_test_support import TOKEN
from shared_support import run_cli
from tls_dates_support import NOW, issue, tls_server, verify_failure

from cellctl.client import CellClient, ServiceError, trusting_ca

pytestmark = pytest.mark.timeout(120)
DAY = datetime.timedelta(days=1)
CASES = {  # case: (valid from, valid to, names in the certificate, OpenSSL's reason, the hint's words)
    "expired": (NOW - 400 * DAY, NOW - 35 * DAY, ("127.0.0.1",), "certificate has expired", "has expired"),
    "not yet valid": (NOW + 30 * DAY, NOW + 400 * DAY, ("127.0.0.1",), "certificate is not yet valid", "is not valid yet"),
    "another name": (NOW - DAY, NOW + 90 * DAY, ("cell.plant.example",), "IP address mismatch",
                     "is not issued for '127.0.0.1': give --url with a name or address the certificate holds"),
    "untrusted": (NOW - DAY, NOW + 90 * DAY, ("127.0.0.1",), "self-signed certificate in certificate chain",
                  "is not trusted: give --ca with the PEM of the CA that signed it"),
}  # fmt: skip


@pytest.mark.parametrize("case", list(CASES))
def test_the_hint_matches_the_certificate_s_fault(
    case: str, tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:  # fmt: skip
    start, end, names, reason, hint = CASES[case]
    pki = issue(tmp_path, "cell", start, end, names=names)
    trusted = issue(tmp_path, "other", NOW - DAY, NOW + 90 * DAY)["ca"] if case == "untrusted" else pki["ca"]
    with tls_server(pki["chain"], pki["key"]) as port:
        assert reason in verify_failure(port, trusted).verify_message  # what any client finds
        url = f"https://127.0.0.1:{port}"
        with pytest.raises(ServiceError) as err:
            CellClient(url, token=TOKEN, verify=trusting_ca(trusted)).status()
        said = str(err.value)
        assert f"cannot reach the cell service at {url}: CERTIFICATE_VERIFY_FAILED: {reason}" in said, said
        assert hint in said and TOKEN not in said, said
        assert ("give --ca" in said) == (case == "untrusted"), said  # another CA helps only an untrusted issuer
        monkeypatch.setenv("CELLCTL_TOKEN", TOKEN)
        rc, out, errs = run_cli(capsys, "status", "--url", url, "--ca", str(trusted))
    assert rc == 1 and out == "" and len(errs.strip().splitlines()) == 1 and hint in errs, errs
