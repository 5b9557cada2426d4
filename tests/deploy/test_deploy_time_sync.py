"""The unit waits for a synced clock, and a start refused because the clock stands behind is restarted.

deploy/cellctl.service is ordered after time-sync.target (and network-online.target) and verifies with
`systemd-analyze verify`; the README's install steps enable what makes time-sync.target mean a synced clock
(systemd-time-wait-sync.service or chrony-wait.service). A real `cellctl serve` whose HTTPS certificate is not valid
yet by the OS clock exits with a status the unit restarts (Restart=on-failure, not in RestartPreventExitStatus); one
whose certificate has expired exits with the status the unit does not restart."""

from __future__ import annotations

import datetime as dt
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from service_test_support import sim_toml
from shared_support import free_port, skip_or_fail
from tls_dates_support import issue

REPO = Path(__file__).resolve().parents[2]
UNIT = REPO / "deploy" / "cellctl.service"
INSTALLED_EXEC = "/opt/cellctl/.venv/bin/cellctl"
DAY = dt.timedelta(days=1)


def _settings() -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for line in UNIT.read_text().splitlines():
        if "=" in line and not line.lstrip().startswith(("#", ";", "[")):
            key, _, value = line.partition("=")
            out.setdefault(key.strip(), []).extend(value.split())
    return out


def test_the_unit_starts_after_time_sync_and_the_install_steps_make_it_wait_for_the_clock(tmp_path: Path) -> None:
    s = _settings()
    assert {"time-sync.target", "network-online.target"} <= set(s["After"]), s["After"]
    analyze = shutil.which("systemd-analyze")
    if analyze is None:
        skip_or_fail("systemd-analyze is not installed", "scripts/system-packages installs Debian's systemd for it")
    unit = tmp_path / "cellctl.service"
    unit.write_text(UNIT.read_text().replace(INSTALLED_EXEC, str(Path(sys.executable).with_name("cellctl"))))
    r = subprocess.run([analyze, "verify", str(unit)], capture_output=True, text=True, timeout=60, check=False)
    assert r.returncode == 0 and not r.stderr.strip(), f"rc {r.returncode}: {r.stdout}{r.stderr}"
    readme = (REPO / "README.md").read_text()
    start = readme.index("**Installing on a cell's PC**")
    steps = readme[start : readme.index("```\n", readme.index("```sh", start) + 5)]
    assert re.search(r"systemctl enable systemd-time-wait-sync\.service\b", steps), steps
    assert "chrony-wait.service" in steps, steps
    assert steps.index("time-wait-sync") < steps.index("systemctl enable --now cellctl"), steps


@pytest.mark.timeout(180)
@pytest.mark.parametrize(("start", "end", "restarted"), [(30, 400, True), (-400, -35, False)], ids=["not_yet_valid", "expired"])
def test_serve_refused_by_a_certificate_not_valid_yet_is_restarted_by_the_unit(
    tmp_path: Path, start: int, end: int, restarted: bool
) -> None:
    now = dt.datetime.now(dt.timezone.utc).replace(microsecond=0)
    pki = issue(tmp_path, "cell", now + start * DAY, now + end * DAY)
    text = sim_toml(free_port())
    text, n = re.subn(r"(?m)^\[api\].*$", lambda m: f'{m.group(0)}\ntls_cert = "{pki["chain"]}"\ntls_key = "{pki["key"]}"',
                      text, count=1)  # fmt: skip
    assert n == 1
    cfg = tmp_path / "cell.toml"
    cfg.write_text(text, encoding="utf-8")
    env = {k: v for k, v in os.environ.items() if not k.startswith("CELLCTL_")}
    done = subprocess.run([sys.executable, "-m", "cellctl", "--config", str(cfg), "serve", "--workdir", str(tmp_path)],
                          capture_output=True, text=True, timeout=120, env=env, cwd=tmp_path)  # fmt: skip
    s = _settings()
    assert s["Restart"] == ["on-failure"] and done.returncode != 0, (done.returncode, done.stderr[-2000:])
    assert (str(done.returncode) not in s["RestartPreventExitStatus"]) == restarted, (done.returncode, done.stderr[-2000:])
    said = "is not valid yet" if restarted else "has expired"
    assert f"error: the REST API cannot serve HTTPS: api.tls_cert: {pki['chain']} {said}" in done.stderr, done.stderr[-2000:]
    assert ("clock stands behind" in done.stderr) == restarted and "Traceback" not in done.stderr, done.stderr[-2000:]
