"""The disk check when a file system does not answer: /status says "unknown" with no stale free figure,
names the path and the cause, and a partial measurement (the images' own disk failing) is never "ok"."""

from __future__ import annotations

import errno
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace

import pytest
from test_store_retention import rig  # noqa: F401 - the fixture: store, alarms, fake disk, settable clock

from cellctl.api.schemas_cell import StorageStatus
from cellctl.cell.alarms import AlarmCode
from cellctl.config.store import RetentionConfig
from cellctl.service.retention import ALARM_SOURCE, StorageRetention
from cellctl.service.retention_plan import GB, DiskUsage

EIO_TEXT = os.strerror(errno.EIO)  # "Input/output error": the cause /status must keep


def _broken(_path: Path) -> DiskUsage:
    raise OSError(errno.EIO, EIO_TEXT)  # statvfs fails: an I/O error, a stale NFS handle


@pytest.fixture
def other_fs(rig: SimpleNamespace) -> Iterator[Path]:  # noqa: F811
    """A folder on another file system than the test's tmp folder (tmpfs /dev/shm)."""
    if not Path("/dev/shm").is_dir():
        pytest.skip("needs /dev/shm (a second file system)")
    folder = Path(tempfile.mkdtemp(prefix="cellctl-images-", dir="/dev/shm"))
    try:
        if folder.stat().st_dev == rig.tmp.stat().st_dev:
            pytest.skip("/dev/shm is on the same file system as the tmp folder")
        yield folder
    finally:
        shutil.rmtree(folder, ignore_errors=True)


async def test_a_failed_disk_check_says_unknown_with_no_stale_figure_and_keeps_the_cause(rig: SimpleNamespace) -> None:  # noqa: F811
    ret = rig.make(disk_warn_free_gb=10, disk_stop_free_gb=2)
    assert await ret.check_disk() == "ok" and ret.status()["free_disk_gb"] == 100.0
    rig.clock.advance(minutes=5)
    ret._disk_usage = _broken
    await ret._guarded("disk check", ret.check_disk)  # what the background loop runs
    st = ret.status()
    assert st["disk"] == "unknown" and st["free_disk_gb"] is None
    assert st["checked_utc"] == rig.clock().isoformat(timespec="seconds")  # the failed check is the latest one
    assert EIO_TEXT in st["last_error"] and str(rig.tmp) in st["last_error"] and "(database)" in st["last_error"]
    assert StorageStatus.model_validate(st).disk == "unknown"  # a value the /status schema documents
    ret._disk_usage = rig.disk  # the file system answers again
    assert await ret.check_disk() == "ok"
    await ret._guarded("disk check", ret.check_disk)
    st = ret.status()
    assert (st["disk"], st["free_disk_gb"], st["last_error"]) == ("ok", 100.0, None)


async def test_the_images_disk_failing_is_reported_and_the_state_is_not_ok(rig: SimpleNamespace, other_fs: Path) -> None:  # noqa: F811
    def disk(p: Path) -> DiskUsage:
        return _broken(p) if p.is_relative_to(other_fs) else shutil.disk_usage(p)  # the real figure elsewhere

    ret = StorageRetention(RetentionConfig(disk_warn_free_gb=0.001, disk_stop_free_gb=0.0005), rig.store, rig.alarms,
                           image_dir=other_fs, db_path=rig.tmp / "cell.db", clock=rig.clock, disk_usage=disk)  # fmt: skip
    await ret._guarded("disk check", ret.check_disk)
    st = ret.status()
    assert st["disk"] == "unknown"  # the database's disk has room, but the images' may be full
    assert st["free_disk_gb"] == pytest.approx(shutil.disk_usage(rig.tmp).free / GB, abs=0.5)  # the disk it measured
    assert str(other_fs) in st["last_error"] and "(images)" in st["last_error"] and EIO_TEXT in st["last_error"]
    ret._disk_usage = shutil.disk_usage  # both answer again
    assert await ret.check_disk() == "ok" and ret.status()["last_error"] is None


async def test_a_low_disk_measured_beside_a_failing_one_still_raises_its_alarm(rig: SimpleNamespace, other_fs: Path) -> None:  # noqa: F811
    def disk(p: Path) -> DiskUsage:
        return _broken(p) if p.is_relative_to(other_fs) else DiskUsage(500 * GB, 497 * GB, 3 * GB)

    ret = StorageRetention(RetentionConfig(disk_warn_free_gb=10, disk_stop_free_gb=2), rig.store, rig.alarms,
                           image_dir=other_fs, db_path=rig.tmp / "cell.db", clock=rig.clock, disk_usage=disk)  # fmt: skip
    assert await ret.check_disk() == "low"  # at least low: what is known is not hidden behind "unknown"
    assert rig.alarms.find_active(AlarmCode.DISK_SPACE_LOW, ALARM_SOURCE) is not None
    assert ret.status()["free_disk_gb"] == 3.0 and "(images)" in ret.status()["last_error"]
