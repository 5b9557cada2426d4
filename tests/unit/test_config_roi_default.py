"""``vision.roi`` left out is the whole frame of ``layout.camera`` (it was a fixed 2048 x 2048: a 1920 x 1200 camera
was refused over a setting nobody wrote, a 2448 x 2048 one never searched its right 400 px); one given is kept. The
configurations are config/hardware.example.toml with the camera's data sheet changed, as commissioning step 1 asks."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from cellctl.config import ConfigError, load_config

HARDWARE = Path(__file__).resolve().parents[2] / "config" / "hardware.example.toml"


def _with_camera(tmp_path: Path, width: int, height: int, extra: str = "") -> Path:
    text = HARDWARE.read_text(encoding="utf-8")
    text, n = re.subn(r"\[layout\.camera\](.*?)\nwidth_px = 2048\nheight_px = 2048\nfx = 5250\.0\nfy = 5250\.0\ncx = 1024\.0\ncy = 1024\.0",
                      rf"[layout.camera]\1\nwidth_px = {width}\nheight_px = {height}\nfx = 5250.0\nfy = 5250.0\ncx = {width / 2}\ncy = {height / 2}",
                      text, count=1, flags=re.S)  # fmt: skip
    assert n == 1
    cfg = tmp_path / "cell.toml"
    cfg.write_text(text + extra, encoding="utf-8")
    return cfg


@pytest.mark.parametrize(("width", "height"), [(1920, 1200), (2448, 2048), (2048, 2048)])
def test_the_roi_left_out_is_the_cameras_whole_frame(tmp_path: Path, width: int, height: int) -> None:
    roi = load_config(_with_camera(tmp_path, width, height)).vision.roi
    assert (roi.x_px, roi.y_px, roi.width_px, roi.height_px) == (0, 0, width, height)


def test_a_roi_given_is_kept_and_still_checked_against_the_frame(tmp_path: Path) -> None:
    given = "\n[vision.roi]\nx_px = 100\ny_px = 50\nwidth_px = 1500\nheight_px = 1000\n"
    roi = load_config(_with_camera(tmp_path, 1920, 1200, given)).vision.roi
    assert (roi.x_px, roi.y_px, roi.width_px, roi.height_px) == (100, 50, 1500, 1000)
    too_wide = given.replace("width_px = 1500", "width_px = 1900")
    with pytest.raises(ConfigError, match=r"vision\.roi: x_px \+ width_px = 2000 exceeds the image width 1920 px"):
        load_config(_with_camera(tmp_path, 1920, 1200, too_wide))
