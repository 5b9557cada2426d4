"""The benchmark runs end to end (its figures are printed by `python -m keyence_lkg.bench`, not asserted)."""

from __future__ import annotations

import pytest

from keyence_lkg import bench


@pytest.mark.parametrize(("dialect", "wire_bytes"), [("LK-G3001", 3 + 12), ("LK-G5001", 6 + 15)])
def test_bench_measures_one_exchange(dialect: str, wire_bytes: int) -> None:
    result = bench.run(dialect, count=30, baud=115200)
    # M1\r + M1,+sxx.xxx\r, and MS,01\r + MS,01,+sxx.xxx\r at 0.001 mm
    assert result.bytes_per_exchange == wire_bytes
    assert result.wire_us == pytest.approx(wire_bytes * 10 / 115200 * 1e6)
    assert result.cpu_us > 0 and result.wall_us > 0
    assert result.share == pytest.approx(result.cpu_us / result.wire_us)


def test_bench_main_prints_the_table(capsys: pytest.CaptureFixture[str]) -> None:
    bench.main(["--count", "20", "--dialect", "LK-G3001"])
    out = capsys.readouterr().out
    assert "CPU/wire" in out and "LK-G3001" in out and "target: driver CPU under 10 %" in out
