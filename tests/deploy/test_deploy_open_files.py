"""The systemd unit lifts the open files limit above systemd's default soft limit of 1024 (review r4, D2)."""

from __future__ import annotations

from pathlib import Path

from cellctl.service.http_guard import MAX_CONNECTIONS

UNIT = Path(__file__).resolve().parents[2] / "deploy" / "cellctl.service"


def test_the_unit_sets_limit_nofile_well_above_the_http_connection_cap() -> None:
    values = [line.partition("=")[2].strip() for line in UNIT.read_text().splitlines() if line.startswith("LimitNOFILE=")]
    assert len(values) == 1, "deploy/cellctl.service: set LimitNOFILE once in [Service]"
    soft = int(values[0].split(":")[0])  # "soft:hard" or one value for both
    assert soft >= 65536 > 4 * MAX_CONNECTIONS
