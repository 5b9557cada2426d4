"""A job a dead process left running says, once recovered, that what it collected is gone and what to do (a SIGKILL
keeps no samples: they were in the dead process's memory), read back with sqlite3."""

from __future__ import annotations

import sqlite3
from pathlib import Path

from cellctl.store import CellStore


def test_a_recovered_job_says_its_samples_were_not_kept_and_to_start_it_again(tmp_path: Path) -> None:
    with CellStore.open(tmp_path / "c.db") as store:
        job = store.create_job("hand_eye", actor="op", source="cli", options={}, version_before=None).id
        assert store.recover_jobs() == [job]
    with sqlite3.connect(tmp_path / "c.db") as peer:
        state, error = peer.execute("SELECT state, error FROM jobs WHERE id = ?", (job,)).fetchone()
    assert state == "interrupted"
    assert error.startswith("interrupted: the service stopped while the job ran") and "start the job again" in error, error
