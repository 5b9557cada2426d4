"""Retention when the image folder is not what the records say: a folder away for a while (an
unmounted disk or share) costs no image and marks none missing, a file marked missing that is back
gets its reference back (never deleted as a leftover), and a file whose name is not UTF-8 is an
orphan file like any other instead of stopping every pass."""

from __future__ import annotations

import logging
import os
from datetime import timedelta
from types import SimpleNamespace

import pytest
from test_store_retention import add_cycle, rig  # noqa: F401 - the fixture: store, alarms, fake disk, settable clock

MISSING_REASON = "file missing on disk when retention looked"  # what a reference without its file says


def _names(rig: SimpleNamespace) -> list[str]:
    return sorted(p.name for p in rig.images.iterdir())


def _shots(*cycles: int) -> list[str]:
    return sorted(f"cycle-{c}-shot{k}.png" for c in cycles for k in (0, 1))


async def _pruned(rig: SimpleNamespace, *cycles: int) -> list[tuple[str, str | None]]:
    return [(i.name, i.pruned_reason) for c in cycles for i in (await rig.store.cycle(c)).images if i.pruned]


async def test_an_absent_image_folder_skips_the_image_part_says_so_and_costs_no_image(rig: SimpleNamespace) -> None:
    ret = rig.make(images_days=30)
    await ret.run_once()  # before the first cycle there is no folder yet, and nothing to lose: no problem
    assert ret.status()["last_error"] is None
    done = await rig.sync(lambda s: add_cycle(s, rig.images, 1))
    running = await rig.sync(lambda s: add_cycle(s, rig.images, 2, finish=False))
    away = rig.tmp / "images.unmounted"
    rig.images.rename(away)
    report = await ret.run_once()
    assert report.images_missing == 0 and await _pruned(rig, done, running) == []
    problem = ret.status()["last_error"]
    assert problem and str(rig.images) in problem and "is not there" in problem and "unmounted" in problem
    away.rename(rig.images)
    rig.clock.advance(minutes=5)
    await ret.run_once()
    assert _names(rig) == _shots(done, running)
    assert ret.status()["last_error"] is None  # back: the problem is gone from /status
    rig.clock.advance(days=31)  # and age pruning goes on as before
    assert (await ret.run_once()).images_pruned == 2 and _names(rig) == _shots(running)


async def test_an_empty_mount_point_is_not_every_file_missing(rig: SimpleNamespace) -> None:
    done = await rig.sync(lambda s: add_cycle(s, rig.images, 1))
    away = rig.tmp / "images.unmounted"
    rig.images.rename(away)
    rig.images.mkdir()  # the mount point without its disk, and the recorder writes the next cycle into it
    running = await rig.sync(lambda s: add_cycle(s, rig.images, 2, finish=False))
    ret = rig.make(images_days=30)
    assert (await ret.run_once()).images_missing == 0
    assert await _pruned(rig, done, running) == []
    problem = ret.status()["last_error"]
    assert problem and str(rig.images) in problem and "not one of the 2 image files" in problem
    assert "mount it" in problem


async def test_an_unreadable_image_folder_marks_nothing(rig: SimpleNamespace) -> None:
    done = await rig.sync(lambda s: add_cycle(s, rig.images, 1))
    away = rig.tmp / "images.away"
    rig.images.rename(away)
    rig.images.write_bytes(b"")  # not a folder (tests run as root, so no permission can stop a read)
    ret = rig.make(images_days=30)
    await ret.run_once()
    assert await _pruned(rig, done) == []
    problem = ret.status()["last_error"]
    assert problem and f"the image folder {rig.images} cannot be read" in problem


async def test_a_running_cycles_references_are_never_marked_missing(rig: SimpleNamespace) -> None:
    done = await rig.sync(lambda s: add_cycle(s, rig.images, 1))
    running = await rig.sync(lambda s: add_cycle(s, rig.images, 2, finish=False))
    for p in (rig.images / f"cycle-{done}-shot1.png", rig.images / f"cycle-{running}-shot0.png"):
        p.unlink()  # the running cycle's file is not written yet, the done one's was deleted by hand
    report = await rig.make(images_days=30).run_once()
    assert report.images_missing == 1
    assert await _pruned(rig, done, running) == [("shot1", MISSING_REASON)]


async def test_a_file_marked_missing_that_is_back_gets_its_reference_back_and_is_never_a_leftover(
    rig: SimpleNamespace,
) -> None:
    done = await rig.sync(lambda s: add_cycle(s, rig.images, 1))
    back = f"cycle-{done}-shot0.png"
    await rig.store.mark_images_pruned([back], reason=MISSING_REASON)  # e.g. by a pass while the disk was away
    assert await rig.store.pruned_only([back]) == set()  # not a file retention deleted
    ret = rig.make(images_days=30)
    rig.clock.advance(minutes=5)
    report = await ret.run_once()
    assert (report.images_restored, report.images_pruned, report.orphans_deleted) == (1, 0, 0)
    assert _names(rig) == _shots(done) and await _pruned(rig, done) == []
    rig.clock.advance(days=31)  # kept again, it goes by age like the others and says why
    assert (await ret.run_once()).images_pruned == 2 and _names(rig) == []
    assert {r for _, r in await _pruned(rig, done)} == {"retention: older than 30 days"}


async def test_a_file_whose_name_is_not_utf8_is_an_orphan_and_the_pass_goes_on(
    rig: SimpleNamespace, caplog: pytest.LogCaptureFixture
) -> None:
    old = await rig.sync(lambda s: add_cycle(s, rig.images, 1))
    rig.clock.advance(days=40)
    young = await rig.sync(lambda s: add_cycle(s, rig.images, 2))
    odd_old, odd_young = (os.fsencode(rig.images) + b"/cycle-\xff-" + n + b".png" for n in (b"old", b"young"))
    for p, t in ((odd_old, rig.clock() - timedelta(days=31)), (odd_young, rig.clock())):
        with open(p, "wb") as f:
            f.write(b"x" * 10)
        os.utime(p, (t.timestamp(), t.timestamp()))
    ret = rig.make(images_days=30)
    with caplog.at_level(logging.WARNING, logger="cellctl.service.retention"):
        await ret._guarded_pass()  # what the background loop runs every period_s
        await ret._guarded_pass()
    assert ret.status()["last_error"] is None
    assert _names(rig) == _shots(young) + [os.fsdecode(odd_young)[len(str(rig.images)) + 1 :]]
    assert {r for _, r in await _pruned(rig, old)} == {"retention: older than 30 days"}
    said = [r.getMessage() for r in caplog.records if "not UTF-8" in r.getMessage()]  # each name once, over two passes
    want = [b"cycle-\xff-old.png", b"cycle-\xff-young.png"]
    assert sorted(m.split(" in ")[0] for m in said) == ["retention: " + repr(n) for n in want]
