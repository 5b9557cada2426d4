"""A camera recomputed from the same views gives the same bits, whatever OpenCV's thread pool, and a recompute stores
nothing unless the lens moves a pixel of the image by more than noise.

``cv2.calibrateCameraExtended`` on OpenCV's pool (pthreads) summed in the order its threads finished: 100 runs at 2 threads
gave about 40 different (K, dist), up to 3.5e-6 px apart, and ``cellctl calibrate camera --dataset`` on the dataset of the
camera in use then stored a new version, making every part computed with it stale. The data: the seeded twin's board
views (calib_test_support); the peers: the set file as json reads it from disk (the stored values, bit for bit), and
OpenCV's thread count as cv2 reports it.
"""

from __future__ import annotations

import dataclasses
import json
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import pytest
from calib_test_support import NOW, board_views, camera_outcome, config, scratch

from cellctl.calibration.calibration_set import CalibrationStore
from cellctl.calibration.compute import compute_camera
from cellctl.calibration.recording import record
from cellctl.cli import DEFAULT_CONFIG, main


@pytest.fixture(autouse=True)
def _pool() -> Iterator[None]:
    """OpenCV's thread count as the test found it, put back after."""
    before = cv2.getNumThreads()
    yield
    cv2.setNumThreads(before)


def _set_on_disk(root: Path) -> dict[str, Any]:
    return json.loads((root / (root / "current").read_text().strip()).read_text())  # type: ignore[no-any-return]


def _files(root: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(root.iterdir()) if p.is_file()}


def _stored_on_one_thread() -> tuple[CalibrationStore, dict[str, Any]]:
    """A store holding the camera computed with OpenCV on one thread, and its values as read from the set file."""
    ds, dets = board_views()
    cv2.setNumThreads(1)
    store = CalibrationStore(scratch("one-thread"))
    record(store, compute_camera(ds, config(), dets), ds, config(), NOW)
    return store, _set_on_disk(store.root)["parts"]["camera"]["values"]


def _lens(values: dict[str, Any]) -> tuple[list[float], list[float]]:
    return [float(x) for row in values["K"] for x in row], [float(x) for x in values["dist"]]


def test_the_camera_is_the_same_bits_on_any_opencv_thread_count() -> None:
    _, stored = _stored_on_one_thread()
    ds, dets = board_views()
    for threads in (2, 4, 8):
        cv2.setNumThreads(threads)
        for _ in range(12):
            values = json.loads(json.dumps(compute_camera(ds, config(), dets).values))  # as the set file holds it
            assert _lens(values) == _lens(stored), f"{threads} threads"  # every bit: floats compared with ==
            assert cv2.getNumThreads() == threads  # the pool given back as it was


def test_concurrent_recomputes_are_the_same_bits_and_leave_the_pool_as_it_was() -> None:
    _, stored = _stored_on_one_thread()
    ds, dets = board_views()
    cv2.setNumThreads(4)
    got: list[tuple[list[float], list[float]]] = []

    def run() -> None:
        for _ in range(6):
            got.append(_lens(json.loads(json.dumps(compute_camera(ds, config(), dets).values))))

    workers = [threading.Thread(target=run) for _ in range(3)]
    for w in workers:
        w.start()
    for w in workers:
        w.join()
    assert len(got) == 18 and all(g == _lens(stored) for g in got)
    assert cv2.getNumThreads() == 4


def _recompute(capsys: pytest.CaptureFixture[str], store: CalibrationStore) -> str:
    capsys.readouterr()
    rc = main(["--config", str(DEFAULT_CONFIG), "calibrate", "camera", "--store", str(store.root), "--dataset", str(board_views()[0].root)])
    out = capsys.readouterr().out
    assert rc == 0, out
    return out


def test_recomputing_on_another_thread_count_than_the_stored_camera_stores_nothing(capsys: pytest.CaptureFixture[str]) -> None:
    store, _ = _stored_on_one_thread()
    camera_id, before = _set_on_disk(store.root)["parts"]["camera"]["id"], _files(store.root)
    for threads in (2, 8):
        cv2.setNumThreads(threads)
        out = _recompute(capsys, store)
        assert f"identical to the camera in use ({camera_id}); not stored" in out, out
    assert _files(store.root) == before


def _store_camera(values: dict[str, Any]) -> CalibrationStore:
    """A store whose camera in use came from the shared views, with ``values`` instead of those computed."""
    ds, _ = board_views()
    store = CalibrationStore(scratch("lens"))
    record(store, dataclasses.replace(camera_outcome(), values=values), ds, config(), NOW)
    return store


def _moved(**delta: float) -> dict[str, Any]:
    """The computed camera with cx, k1, k2 moved by ``delta`` (px, and unitless)."""
    v = json.loads(json.dumps(camera_outcome().values))
    v["K"][0][2] += delta.get("cx", 0.0)
    v["dist"][0] += delta.get("k1", 0.0)
    v["dist"][1] += delta.get("k2", 0.0)
    return v


def test_a_camera_in_use_a_few_micropixels_off_the_recompute_is_the_same_lens(capsys: pytest.CaptureFixture[str]) -> None:
    # the thread pool's spread of the last bits: cx 3.2e-6 px, k2 2.9e-8 (about 2.5e-7 px at the image's corners)
    store = _store_camera(_moved(cx=3.2e-6, k2=2.9e-8))
    camera_id, before = _set_on_disk(store.root)["parts"]["camera"]["id"], _files(store.root)
    out = _recompute(capsys, store)
    assert f"identical to the camera in use ({camera_id}); not stored" in out, out
    assert _files(store.root) == before


@pytest.mark.parametrize("delta", [{"cx": 0.002}, {"k1": 2e-6}], ids=["cx_2_millipixels", "k1_corner_0.2_millipixels"])
def test_a_camera_in_use_off_the_recompute_by_more_is_stored_again(capsys: pytest.CaptureFixture[str], delta: dict[str, float]) -> None:
    # k1 + 2e-6 moves the image's corners by f r^3 2e-6 = 5250 * 0.276^3 * 2e-6 = 2.2e-4 px: above 1e-4 px, so stored
    store = _store_camera(_moved(**delta))
    out = _recompute(capsys, store)
    assert "stored as version 2" in out, out
    cam = _set_on_disk(store.root)["parts"]["camera"]["values"]
    assert _lens(cam) == _lens(json.loads(json.dumps(camera_outcome().values)))  # the recomputed lens, bit for bit
