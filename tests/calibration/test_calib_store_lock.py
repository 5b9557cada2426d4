"""Two processes writing one calibration folder (the service's job and an offline ``cellctl calibrate --dataset``):
every version a writer was told it stored holds its part, built on the version before; a writer that finds the
store busy for too long is refused with the holder's pid, and the offline CLI says so in one line."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from calib_test_support import NOW, VALUES
from test_calib_cli import _laser_dataset, _run

import cellctl.calibration.set_lock as set_lock
from cellctl.calibration.calibration_set import CalibrationSetError, CalibrationStore, make_part

N = 80  # commits per writer

# One writer: commits ``n`` versions of its part, each with a marker in its values; prints what it was told.
WRITER = """
import json, sys, time
from pathlib import Path
from datetime import datetime
from cellctl.calibration.calibration_set import CalibrationStore, make_part
root, name, n, go, values, when = Path(sys.argv[1]), sys.argv[2], int(sys.argv[3]), Path(sys.argv[4]), json.loads(sys.argv[5]), datetime.fromisoformat(sys.argv[6])
store = CalibrationStore(root)
while not go.exists():
    time.sleep(0.001)
for i in range(n):
    v = json.loads(json.dumps(values))
    v[sys.argv[7]][int(sys.argv[8])] = float(i)
    saved = store.commit(name, make_part(name, values=v, method="test", when=when, valid_days=90.0), note=f"{name}-{i}", now=when)
    print(json.dumps([saved.version, i]), flush=True)
"""

# Another process in the middle of a commit: its set file is being written (a slow disk) for ``hold_s``.
SLOW_COMMIT = """
import sys, time
from pathlib import Path
import cellctl.calibration.calibration_set as cs
dump = cs.dump_calibration_set
def slow_dump(cal):
    print("writing", flush=True)
    time.sleep(float(sys.argv[2]))
    return dump(cal)
cs.dump_calibration_set = slow_dump
part = cs.make_part("hand_eye", values={"T_H_C": __import__("json").loads(sys.argv[3])}, method="other", when=cs.datetime.now(cs.timezone.utc), valid_days=90.0)
print(cs.CalibrationStore(Path(sys.argv[1])).commit("hand_eye", part, note="the other writer").version, flush=True)
"""


def _python(code: str, *args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-c", code, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _part(name: str, **change: Any) -> Any:
    return make_part(name, values={**VALUES[name], **change}, method="test", when=NOW, valid_days=90.0)


def _other_writer(root: Path, hold_s: float) -> subprocess.Popen[str]:
    """A second process that holds the store (mid-commit) for ``hold_s`` s; returns once it holds it."""
    proc = _python(SLOW_COMMIT, str(root), str(hold_s), json.dumps(VALUES["hand_eye"]["T_H_C"]))
    assert proc.stdout is not None and proc.stdout.readline().strip() == "writing", proc.stderr.read() if proc.stderr else ""
    return proc


def test_two_processes_committing_keep_every_version_with_its_part(tmp_path: Path) -> None:
    root, go = tmp_path / "calibration", tmp_path / "go"
    CalibrationStore(root).commit("hand_eye", _part("hand_eye"), note="base", now=NOW)
    writers = {  # part -> (the values field and index that carry the commit's number)
        "laser": ("r", 1),
        "camera": ("dist", 4),
    }
    procs = {name: _python(WRITER, str(root), name, str(N), str(go), json.dumps(VALUES[name]), NOW.isoformat(), field, str(at))
             for name, (field, at) in writers.items()}  # fmt: skip
    time.sleep(0.5)
    go.touch()
    told: dict[int, tuple[str, int]] = {}
    for name, proc in procs.items():
        out, err = proc.communicate(timeout=120)
        assert proc.returncode == 0 and not err, err
        for line in out.splitlines():
            version, i = json.loads(line)
            assert version not in told, f"{name}-{i} and {told[version]} were both told version {version}"
            told[version] = (name, i)
    assert len(told) == 2 * N
    # The truth is the folder, read as plain JSON: every version the writers were told holds their part, built on
    # the version before it (the other writer's part unchanged from there), and nothing else is left in the folder.
    files = sorted(p.name for p in root.iterdir() if p.is_file())
    assert files == [".lock", "current"] + [f"set-{v:06d}.json" for v in range(1, 2 * N + 2)]
    docs = {v: json.loads((root / f"set-{v:06d}.json").read_text()) for v in range(1, 2 * N + 2)}
    for version, (name, i) in told.items():
        doc, prev = docs[version], docs[version - 1]
        field, at = writers[name]
        assert doc["note"] == f"{name}-{i}" and doc["parent_version"] == version - 1
        assert doc["parts"][name]["values"][field][at] == i
        other = next(n for n in writers if n != name)
        assert doc["parts"][other] == prev["parts"][other] and doc["parts"]["hand_eye"] == docs[1]["parts"]["hand_eye"]
    assert (root / "current").read_text().strip() == f"set-{2 * N + 1:06d}.json"


def test_a_writer_waits_for_the_other_then_is_refused_naming_its_pid(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    root = tmp_path / "calibration"
    CalibrationStore(root).commit("laser", _part("laser"), note="base", now=NOW)
    other = _other_writer(root, hold_s=1.5)
    try:
        t0 = time.monotonic()
        monkeypatch.setattr(set_lock, "LOCK_WAIT_S", 0.3)
        with pytest.raises(CalibrationSetError) as refused:
            CalibrationStore(root).commit("camera", _part("camera"), now=NOW)
        waited = time.monotonic() - t0
        text = str(refused.value)
        assert f"the calibration store {root} is in use by another process (pid {other.pid})" in text, text
        assert "try again" in text and 0.3 <= waited < 1.2, (text, waited)
        # Waiting long enough: stored after the other writer, on top of its version (both parts kept).
        mine = CalibrationStore(root, lock_timeout_s=10.0).commit("camera", _part("camera"), note="mine", now=NOW)
        theirs = int(other.communicate(timeout=10)[0].strip())
    finally:
        other.kill()
        other.wait()
    assert (theirs, mine.version) == (2, 3)
    doc = json.loads((root / "set-000003.json").read_text())
    assert doc["parent_version"] == 2 and set(doc["parts"]) >= {"laser", "hand_eye", "camera"}
    assert doc["parts"]["hand_eye"]["method"] == "other"


def test_the_offline_cli_refused_by_a_busy_store_prints_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    root = tmp_path / "store"
    ds = _laser_dataset()
    CalibrationStore(root).commit("camera", _part("camera"), note="base", now=NOW)
    monkeypatch.setattr(set_lock, "LOCK_WAIT_S", 0.3)
    other = _other_writer(root, hold_s=3.0)
    try:
        capsys.readouterr()
        assert _run("calibrate", "laser", "--store", str(root), "--dataset", str(ds.root)) == 1
    finally:
        other.kill()
        other.wait()
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert f"is in use by another process (pid {other.pid})" in err and "try again" in err, err
    assert sorted(p.name for p in root.glob("set-*.json")) == ["set-000001.json"]  # nothing stored by the refused run
    assert os.listdir(root).count("current") == 1
