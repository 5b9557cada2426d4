"""Helpers of the hardware-mode process tests: child processes that leave nothing behind, free
loopback ports, the GenTL producer of the genicam wheel, and a hardware config written as TOML."""

from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, IO

import pytest
from shared_support import LOOPBACK, free_port, on_ci, tlsimu_path  # noqa: F401 - the hardware tests import them from here

ROOT = Path(__file__).resolve().parents[2]
HERE = Path(__file__).resolve().parent
PY = sys.executable
NO_TWIN = HERE / "no_twin.py"
TLSIMU_MONO = "SN_InterfaceA_0"  # TLSimu's monochrome camera


# -- TOML ---------------------------------------------------------------------------------------


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)  # a TOML basic string is a JSON string for what a config holds
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} {v!r} as a TOML value")


def dump_toml(data: dict[str, Any]) -> str:
    """A TOML document for a config mapping (tables, arrays of tables, scalars, arrays; no None)."""
    lines: list[str] = []

    def table(node: dict[str, Any], path: list[str]) -> None:
        subtables: list[tuple[str, Any]] = []
        for key, v in node.items():
            if v is None:
                raise ValueError(f"{'.'.join([*path, key])}: TOML has no null; leave the key out")
            if isinstance(v, dict) or (isinstance(v, list) and v and all(isinstance(x, dict) for x in v)):
                subtables.append((key, v))
            else:
                lines.append(f"{json.dumps(key) if not key.isidentifier() else key} = {_value(v)}")
        for key, v in subtables:
            name = ".".join([*path, key])
            if isinstance(v, dict):
                lines.extend(["", f"[{name}]"])
                table(v, [*path, key])
            else:
                for item in v:
                    lines.extend(["", f"[[{name}]]"])
                    table(item, [*path, key])

    table(data, [])
    return "\n".join(lines) + "\n"


# -- child processes ----------------------------------------------------------------------------


def _group_members(pgid: int) -> list[int]:
    """Live processes (not zombies) in process group ``pgid``."""
    members = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()  # state ppid pgrp ...
        if int(fields[2]) == pgid and fields[0] != "Z":
            members.append(int(entry))
    return members


class Child:
    """A child process in its own process group, its stderr (and stdout unless piped) in log files."""

    def __init__(self, name: str, argv: list[str], logs: Path, *, env: dict[str, str] | None = None,
                 cwd: Path | None = None, pipe_stdout: bool = False) -> None:  # fmt: skip
        self.name = name
        logs.mkdir(parents=True, exist_ok=True)
        self.out_path = logs / f"{name}.out"
        self.err_path = logs / f"{name}.err"
        self._err: IO[bytes] = open(self.err_path, "wb")
        self._out: IO[bytes] | None = None if pipe_stdout else open(self.out_path, "wb")
        self.proc = subprocess.Popen(
            argv, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE if pipe_stdout else self._out, stderr=self._err,
            env=env, cwd=cwd, start_new_session=True,
        )  # fmt: skip
        self.pgid = self.proc.pid
        self.leftovers: list[int] = []

    def read_line(self, timeout_s: float) -> str:
        """The next line on a piped stdout; fails (with the logs) if none comes in time."""
        assert self.proc.stdout is not None
        fd = self.proc.stdout.fileno()
        buf = b""
        deadline = time.monotonic() + timeout_s
        while not buf.endswith(b"\n"):
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([fd], [], [], left)[0]:
                pytest.fail(f"{self.name} printed no line within {timeout_s:g} s\n{self.logs()}")
            chunk = os.read(fd, 1)
            if not chunk:
                pytest.fail(f"{self.name} ended (exit {self.proc.wait()}) before printing its line\n{self.logs()}")
            buf += chunk
        return buf.decode()

    def logs(self) -> str:
        out = self.out_path.read_text(errors="replace") if self._out is not None else ""
        return f"--- {self.name} stdout ---\n{out[-4000:]}\n--- {self.name} stderr ---\n{self.err_path.read_text(errors='replace')[-6000:]}"

    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self, timeout_s: float = 15.0) -> int | None:
        """SIGTERM, wait; SIGKILL the whole group if it lingers. Returns the exit code of the graceful stop (None: killed)."""
        code: int | None = None
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                code = self.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                code = None
        else:
            code = self.proc.returncode
        self.leftovers = _group_members(self.pgid)  # still alive after the graceful stop: left behind
        for pid in self.leftovers:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(5.0)
        for f in (self._out, self._err, self.proc.stdout):
            if f is not None:
                f.close()
        return code

    def alive_in_group(self) -> list[int]:
        """Processes of this child's group alive now (after :meth:`stop` there must be none)."""
        return _group_members(self.pgid)
