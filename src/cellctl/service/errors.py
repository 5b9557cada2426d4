"""Why the service cannot be built or started: the errors ``serve`` turns into its exit status.

Kept apart from :mod:`cellctl.service.compose` so that the command line names them without importing the
whole service (every ``cellctl`` command pays for what the command line imports).
"""

from __future__ import annotations


class ServiceError(RuntimeError):
    """The service cannot be built from this configuration; the message says what to change."""


class ServiceConfigError(ServiceError):
    """A configuration problem found at start (a secret, certificate or key file, or a folder or file the configuration
    names, such as ``[store] path`` or ``calibration.directory``, that cannot be used): starting again cannot help, so
    ``serve`` exits 2, not 1 (a port another program holds can clear; that stays a ServiceError)."""


class ServiceClockBehind(ServiceError):
    """A certificate the service presents (opcua.certificate, api.tls_cert, mqtt.tls.cert_file) is not valid yet by this
    computer's clock: the clock stands behind (at boot before NTP has set it, a flat RTC battery). A start once the clock
    is right succeeds, so ``serve`` exits 1 and systemd starts it again (deploy/cellctl.service: Restart=on-failure);
    an expired or unusable certificate stays a ServiceConfigError (exit 2)."""
