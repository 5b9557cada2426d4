"""The log: --log-level, JSON lines, and a repeated message (a device's link down every second) collapsed with its count."""

from __future__ import annotations

import io
import json
import logging
from collections.abc import Iterator

import pytest

from cellctl.cli import main
from cellctl.logsetup import RepeatFilter, configure_logging


@pytest.fixture(autouse=True)
def _restore_root_logger() -> Iterator[None]:
    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    yield
    for h in [h for h in root.handlers if h not in handlers]:
        root.removeHandler(h)
    root.setLevel(level)


class Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def test_json_lines_carry_ts_level_logger_message_and_the_traceback() -> None:
    out = io.StringIO()
    configure_logging("info", "json", stream=out)
    log = logging.getLogger("cellctl.test.json")
    log.info("robot %s", "ready")
    try:
        raise RuntimeError("boom")
    except RuntimeError:
        log.exception("it failed")
    log.debug("not shown at info")
    lines = out.getvalue().splitlines()
    assert len(lines) == 2
    first, second = (json.loads(line) for line in lines)
    assert set(first) == {"ts", "level", "logger", "message"}
    assert first["level"] == "INFO" and first["logger"] == "cellctl.test.json" and first["message"] == "robot ready"
    assert first["ts"].endswith("+00:00") and "T" in first["ts"]
    assert second["level"] == "ERROR" and "RuntimeError: boom" in second["exc_info"] and "Traceback" in second["exc_info"]


def test_text_format_and_level() -> None:
    out = io.StringIO()
    configure_logging("error", "text", stream=out)
    logging.getLogger("abb_robot.client").warning("robot: link down: refused")
    logging.getLogger("abb_robot.client").error("robot: broken")
    assert out.getvalue().count("\n") == 1 and "ERROR abb_robot.client: robot: broken" in out.getvalue()


def test_a_repeated_message_is_logged_once_then_with_its_count() -> None:
    clock = Clock()
    out = io.StringIO()
    handler = configure_logging("info", "text", stream=out)
    assert [type(f) for f in handler.filters] == [RepeatFilter] and handler.filters[0].window_s == 60.0  # type: ignore[union-attr]
    handler.filters.clear()
    handler.addFilter(RepeatFilter(60.0, clock=clock))
    log = logging.getLogger("abb_robot.client")
    for _ in range(60):  # the controller is away: every second the driver says so
        log.warning("%s: link down: %s", "robot", "the controller closed the connection")
        clock.now += 1.0
    log.warning("%s: link down: %s", "robot", "the controller closed the connection")
    log.info("robot: connected")  # another message is not held back
    lines = out.getvalue().splitlines()
    assert len(lines) == 3, lines
    assert lines[0].endswith("robot: link down: the controller closed the connection")
    assert lines[1].endswith("robot: link down: the controller closed the connection (repeated 59 times in the last 60 s)")
    assert lines[2].endswith("robot: connected")


def test_the_repeat_filter_keys_on_logger_level_and_text() -> None:
    clock = Clock()
    f = RepeatFilter(10.0, clock=clock, max_keys=4)

    def rec(name: str, level: int, msg: str) -> logging.LogRecord:
        return logging.LogRecord(name, level, __file__, 1, msg, None, None)

    assert f.filter(rec("a", logging.WARNING, "x"))
    assert not f.filter(rec("a", logging.WARNING, "x"))
    assert f.filter(rec("b", logging.WARNING, "x")) and f.filter(rec("a", logging.ERROR, "x")) and f.filter(rec("a", logging.WARNING, "y"))
    clock.now += 11.0
    r = rec("a", logging.WARNING, "x")
    assert f.filter(r) and r.getMessage() == "x (repeated 1 time in the last 11 s)"
    for k in range(10):
        assert f.filter(rec("c", logging.INFO, f"distinct {k}"))
    assert len(f._seen) <= 4  # bounded: the oldest go


def test_log_level_and_format_options_reach_the_root_logger(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--log-level", "debug", "--log-format", "json", "config", "check"]) == 0
    assert logging.getLogger().level == logging.DEBUG
    logging.getLogger("cellctl.test").debug("hello")
    err = capsys.readouterr().err.strip().splitlines()
    assert json.loads(err[-1])["message"] == "hello"
    assert main(["config", "check", "--log-level", "ERROR"]) == 0  # after the command, any case
    assert logging.getLogger().level == logging.ERROR
    assert sum(getattr(h, "_cellctl", False) for h in logging.getLogger().handlers) == 1  # replaced, not stacked
