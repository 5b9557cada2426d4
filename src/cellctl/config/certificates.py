"""Certificates the service presents (api.tls_cert, opcua.certificate, mqtt.tls.cert_file): their dates and chain order.

One rule for all three: a certificate outside its validity is refused (its peer would refuse it), and one with fewer
than :data:`EXPIRY_WARNING_DAYS` left is warned about, at ``config check`` and at the start.
"""

from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from cryptography import x509

EXPIRY_WARNING_DAYS = 30
"""A presented certificate with fewer days left is warned about (config check, start)."""


def utc_text(when: datetime) -> str:
    """``when`` as the messages write it: minutes, UTC."""
    return when.astimezone(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")


def certificate_dates(
    cert: x509.Certificate, named: str, fix: str, *, refused: str = "clients refuse it", now: datetime | None = None
) -> tuple[str | None, str | None]:
    """(problem, warning) of a certificate the service presents, by this computer's clock (``now``, UTC): the problem
    when it is not valid yet or has expired (then ``refused``), the warning when fewer than
    EXPIRY_WARNING_DAYS remain; ``named`` says the setting and the file, ``fix`` what to do."""
    now = now or datetime.now(timezone.utc)
    start, end = cert.not_valid_before_utc, cert.not_valid_after_utc
    valid = f"valid from {utc_text(start)} to {utc_text(end)}; now {utc_text(now)}"
    if now < start:
        return f"{named} is not valid yet ({valid}), so {refused}: check this computer's clock, or {fix}", None
    if now > end:
        return f"{named} has expired ({valid}), so {refused}: {fix}", None
    days = (end - now).days
    if days < EXPIRY_WARNING_DAYS:
        return None, f"{named} expires in {days} day(s), on {utc_text(end)}; then {refused}: {fix} before then"
    return None, None


def key_certificate_index(cert_path: Path | str, key_path: Path | str) -> int | None:
    """Which certificate of the PEM file ``cert_path`` (0: the first) holds the public key of the unencrypted PEM key
    ``key_path``; None when none does or a file cannot be read as PEM. A chain whose key's certificate is not first is
    in the wrong order (OpenSSL then says only that key and certificate do not match)."""
    from cryptography import x509
    from cryptography.hazmat.primitives import serialization

    spki = (serialization.Encoding.DER, serialization.PublicFormat.SubjectPublicKeyInfo)
    try:
        certs = x509.load_pem_x509_certificates(Path(cert_path).read_bytes())
        mine = serialization.load_pem_private_key(Path(key_path).read_bytes(), password=None).public_key().public_bytes(*spki)
    except (OSError, ValueError, TypeError):
        return None
    return next((i for i, c in enumerate(certs) if c.public_key().public_bytes(*spki) == mine), None)
