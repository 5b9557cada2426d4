"""Running the EGM peer's loop in a child process, with its state in shared memory.

Layout of the shared block (float64): a reference block (:data:`~abb_robot.egm.peer_core.REF_LEN`
values after a sequence word, written by the owner), a status block
(:data:`~abb_robot.egm.peer_core.STATUS_LEN` values after a sequence word, written by the child),
a ring of reply latencies and a ring of position-stream records (written by the child, whose
status says how many it has written). Each of the two blocks is guarded by a sequence lock: the
writer makes the word odd, writes, makes it even again; a reader retries until it reads the same
even word before and after copying.

The child is a fresh interpreter, ``python -m abb_robot.egm._peer_child <settings-json>
<shm-name>`` (not multiprocessing, which would re-run the owner's main script). It reports
``{"port": ..., "warning": ...}`` or ``{"error": ...}`` as one JSON line on stdout and watches
its stdin besides its socket: a line or the end of stdin (the owner exited) ends it.
"""

from __future__ import annotations

import gc
import json
import socket
import sys
import time
from multiprocessing import resource_tracker
from multiprocessing.shared_memory import SharedMemory
from typing import Any

import numpy as np

from abb_robot.egm.peer_core import (
    REF_LEN,
    STATUS_LEN,
    STREAM_RING,
    STREAM_WIDTH,
    Hooks,
    LatencySink,
    PeerCore,
    StreamSink,
    no_lock,
    serve,
    set_realtime_priority,
    warm_up,
)

RING = 1 << 17
REF_AT = 0
STATUS_AT = REF_AT + 1 + REF_LEN
RING_AT = STATUS_AT + 1 + STATUS_LEN
STREAM_AT = RING_AT + RING
TOTAL = STREAM_AT + STREAM_RING * STREAM_WIDTH


class SeqBlock:
    """A float64 block with a sequence word in front (single writer, any number of readers)."""

    def __init__(self, array: np.ndarray, at: int, length: int) -> None:
        self.word = array[at : at + 1]
        self.data = array[at + 1 : at + 1 + length]

    def write(self, values: np.ndarray | list[float]) -> None:
        self.word[0] += 1.0
        self.data[:] = values
        self.word[0] += 1.0

    def try_read(self) -> np.ndarray | None:
        """A consistent copy, or None if a write is under way (never waits on the writer)."""
        before = self.word[0]
        if before % 2.0 != 0.0:
            return None
        out = self.data.copy()
        return out if self.word[0] == before else None

    def read(self, attempts: int = 200) -> np.ndarray | None:
        """A consistent copy, retrying with short sleeps; None if the writer never finished
        (a writer that died mid-write). The loop's side only ever uses :meth:`try_read`: with
        real-time priority it must not wait on a writer it may be starving."""
        for _ in range(attempts):
            out = self.try_read()
            if out is not None:
                return out
            time.sleep(0.0001)
        return None


class SharedRing(LatencySink):
    """Reply latencies in the shared block (the child writes, the owner reads)."""

    def __init__(self, array: np.ndarray) -> None:
        self.values = array[RING_AT : RING_AT + RING]
        self.count = 0


class SharedStream(StreamSink):
    """Position-stream records in the shared block (the child writes, the owner reads)."""

    def __init__(self, array: np.ndarray) -> None:
        self.rows = stream_rows(array)
        self.count = 0


def stream_rows(array: np.ndarray) -> np.ndarray:
    """The stream ring of the shared block as (STREAM_RING, STREAM_WIDTH) rows."""
    return array[STREAM_AT:TOTAL].reshape(STREAM_RING, STREAM_WIDTH)


def attach(name: str) -> tuple[SharedMemory, np.ndarray]:
    shm = SharedMemory(name=name)
    return shm, np.ndarray((TOTAL,), dtype=np.float64, buffer=shm.buf)


def _report(obj: dict[str, object]) -> None:
    sys.stdout.write(json.dumps(obj) + "\n")
    sys.stdout.flush()


def child_main(settings: Any, shm_name: str) -> None:
    """The child: bind, report, serve until told to stop or orphaned."""
    shm, array = attach(shm_name)
    # The owner created the block and unlinks it; the child only borrows it.
    resource_tracker.unregister(shm._name, "shared_memory")  # type: ignore[attr-defined]  # noqa: SLF001
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.bind((settings.bind_host, settings.port))
    except OSError as exc:
        _report({"error": f"cannot bind UDP {settings.bind_host}:{settings.port} ({exc.strerror})"})
        sock.close()
        shm.close()
        return
    sock.setblocking(False)
    warning = None
    if settings.rt_priority is not None:
        warning = set_realtime_priority(settings.rt_priority)
    _report({"port": int(sock.getsockname()[1]), "warning": warning})
    try:
        _serve_on(array, sock, settings)
    finally:
        sock.close()
        del array  # no view may outlive the block: close() unmaps it even while an array still points into it
        try:
            shm.close()
        except BufferError:
            pass  # a view still exported (a traceback holding _serve_on's frame); the mapping goes with the process


def _serve_on(array: np.ndarray, sock: socket.socket, settings: Any) -> None:
    """Serve on ``sock`` until told to stop, the reference, status and rings in the shared ``array``; the views of
    the block made here (and the core's rings) are dropped when it returns, before the caller closes the block."""
    ref = SeqBlock(array, REF_AT, REF_LEN)
    status = SeqBlock(array, STATUS_AT, STATUS_LEN)
    core = PeerCore(
        controller_host=settings.controller_host,
        receive_timeout_s=settings.receive_timeout_s,
        latency=SharedRing(array),
        stream=SharedStream(array),
        preferred=settings.preferred,
    )
    vector = np.zeros(STATUS_LEN)
    last_ref_word = -1.0

    def before_batch() -> None:
        nonlocal last_ref_word
        word = ref.word[0]
        if word != last_ref_word:
            values = ref.try_read()
            if values is not None:  # torn: keep the current reference, look again next cycle
                last_ref_word = word
                core.apply_reference(values)

    def after_batch() -> None:
        core.export(vector)
        status.write(vector)

    core.export(vector)
    status.write(vector)
    warm_up()
    gc.freeze()  # everything loaded stays: keep collections short inside the 4 ms cycle
    try:
        serve(sock, core, settings.max_rate_hz,
              Hooks(lock=no_lock(), keep_going=lambda: True, wake_fds=[sys.stdin], before_batch=before_batch,
                    after_batch=after_batch))
    finally:
        core.latency = LatencySink(1)
        core.stream = StreamSink(1)

SETTING_FIELDS = ("port", "bind_host", "controller_host", "max_rate_hz", "receive_timeout_s", "rt_priority")


def command(settings: Any, shm_name: str, *, port: int, preferred: tuple[str, ...] = ()) -> list[str]:
    """The child's command line for these settings (an EgmPeerSettings), binding ``port``, preferring the
    controller's IPs ``preferred`` (resolved)."""
    fields = {name: getattr(settings, name) for name in SETTING_FIELDS}
    fields["port"], fields["preferred"] = port, list(preferred)
    return [sys.executable, "-m", "abb_robot.egm._peer_child", json.dumps(fields), shm_name]
