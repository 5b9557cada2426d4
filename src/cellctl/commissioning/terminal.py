"""Following a commissioning job in a terminal: progress bar, prompts answered at the keyboard, Ctrl-C cancels.

The job runs in the service; this side only watches the event stream (``job`` and ``prompt``
events), shows the open prompt and sends what the engineer types: Enter confirms (with the
default value, if the prompt asks for one), a number answers with that value, ``c`` cancels. A
prompt answered elsewhere (the dashboard, the simulated operator) is shown with who answered it.
Ctrl-C cancels the job: the service stops the robot at once and keeps the partial dataset.
"""

from __future__ import annotations

import math
import queue
import sys
import threading
import time
from typing import Any, TextIO

from cellctl.client import CellClient, ServiceError

FINISHED = frozenset({"done", "refused", "failed", "cancelled", "interrupted"})
BAR_WIDTH = 24
SERVICE_STOPPING = "the service is stopping"
"""The reason the service records for a job it cancelled because it was stopping."""


def _clock(seconds: float | None) -> str:
    if seconds is None:
        return "?"
    s = int(round(max(seconds, 0.0)))
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


class ProgressLine:
    """One progress line: redrawn in place on a terminal, printed every tenth of the way elsewhere."""

    def __init__(self, out: TextIO, what: str) -> None:
        self.out = out
        self.what = what
        self.tty = bool(getattr(out, "isatty", lambda: False)())
        self._shown = False
        self._last_tenth = -1
        self._last: tuple[Any, ...] | None = None

    def update(self, p: dict[str, Any]) -> None:
        key = (p.get("done"), p.get("total"), p.get("message"))
        if key == self._last:
            return
        self._last = key
        done, total = int(p.get("done", 0)), max(int(p.get("total", 0)), 1)
        frac = min(done / total, 1.0)
        bar = "#" * round(frac * BAR_WIDTH) + "." * (BAR_WIDTH - round(frac * BAR_WIDTH))
        left = p.get("time_left_s")
        text = (f"  {self.what} [{bar}] {done}/{total}  {p.get('message', '')}  "
                f"{_clock(p.get('elapsed_s'))} elapsed" + (f", ~{_clock(left)} left" if left is not None else ""))  # fmt: skip
        if self.tty:
            self.out.write("\r" + text[:160].ljust(160))
            self._shown = True
        else:
            tenth = int(frac * 10)
            if tenth != self._last_tenth or total <= 20:
                self._last_tenth = tenth
                self.out.write(text + "\n")
        self.out.flush()

    def clear(self) -> None:
        if self.tty and self._shown:
            self.out.write("\r" + " " * 160 + "\r")
            self.out.flush()
            self._shown = False


def _drop_typed_ahead(lines: queue.Queue[str | None], out: TextIO, stdin: TextIO | None) -> TextIO | None:
    """At a keyboard (a terminal), drop the lines typed before a prompt is shown: only what is typed after
    reading it answers it (an Enter pressed early must never confirm the next prompt, e.g. that the robot's
    path is clear). Piped input is a script's answers, taken in order. Returns None once the input has ended."""
    if stdin is None or not stdin.isatty():
        return stdin
    dropped = 0
    while True:
        try:
            line = lines.get_nowait()
        except queue.Empty:
            break
        if line is None:
            stdin = None
        else:
            dropped += 1
    if dropped:
        out.write(f"    ({dropped} line(s) typed before this prompt were dropped: answer it now)\n")
    return stdin


def _read_lines(stream: TextIO, lines: "queue.Queue[str | None]") -> None:
    for line in stream:
        lines.put(line.rstrip("\n"))
    lines.put(None)


def _show_prompt(out: TextIO, prompt: dict[str, Any], *, asks: bool = True) -> None:
    out.write(f"\n  ? [{prompt['kind']}] {prompt['text']}\n")
    if not asks:
        return
    if prompt.get("value_label"):
        out.write(f"    {prompt['value_label']} [{prompt.get('default')}]  (Enter keeps it, a number answers, c cancels): ")
    else:
        out.write("    [Enter] confirm, c cancel: ")
    out.flush()


def _answer_elsewhere(out: TextIO, url: str, job_id: int, prompt: dict[str, Any]) -> None:
    """Say once that this terminal takes no more answers and where the open prompt can be answered."""
    pid = prompt["id"]
    out.write(f"\n    no more input here (stdin closed): prompt {pid} stays open; answer it on the dashboard "
              f"({url}/#/commissioning) or with POST {url}/jobs/{job_id}/prompts/{pid} (action confirm, cancel or value); "
              f"still following job {job_id} (Ctrl-C cancels it)\n")  # fmt: skip
    out.flush()


def _parse(line: str, prompt: dict[str, Any]) -> tuple[str, float | None] | str:
    text = line.strip().lower()
    if text in ("c", "cancel", "n", "no"):
        return ("cancel", None)
    if text in ("", "y", "yes", "ok", "confirm"):
        return ("confirm", None)
    if prompt.get("value_label"):
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if math.isfinite(value):  # "nan", "inf" and 1e999 are not a measured size: asked again, as any other word
            return ("value", value)
    return f"'{line.strip()}' is not an answer: press Enter to confirm" + (", type a number" if prompt.get("value_label") else "") + " or c to cancel"


def print_result(job: dict[str, Any], out: TextIO) -> None:
    """The job's outcome as the engineer reads it."""
    res = job.get("result") or {}
    state = job["state"]
    if res.get("summary"):
        out.write(f"{res.get('part', job['procedure'])} ({res.get('method', '')}):\n")
        for line in res["summary"]:
            out.write(f"  {line}\n")
        for w in res.get("warnings", []):
            if not (job["procedure"] == "verify" and w in res.get("quality", {}).get("beyond_limits", [])):
                out.write(f"  warning: {w}\n")
    if job.get("dataset"):
        out.write(f"  dataset: {job['dataset']}\n")
    if state == "done":
        version = res.get("stored_version")
        if job["procedure"] == "verify":
            pass
        elif version is not None:
            out.write(f"stored as version {version} of the calibration set\n")
            problems = res.get("ready_problems") or []
            out.write("ready for production\n" if not problems else "still needed before production:\n  - " + "\n  - ".join(problems) + "\n")
        else:
            out.write("not stored (--no-store)\n")
    else:
        label = {"refused": "REFUSED", "failed": "FAILED", "cancelled": "CANCELLED", "interrupted": "INTERRUPTED"}.get(state, state)
        out.write(f"{job['procedure']}: {label}: {job.get('error')}\n")
        if state != "refused" or job.get("dataset"):
            out.write("the calibration set in use is unchanged\n")
    out.flush()


def exit_status(job: dict[str, Any]) -> int:
    if job["state"] != "done":
        return 1
    if job["procedure"] == "verify" and not (job.get("result") or {}).get("quality", {}).get("passed", False):
        return 1
    return 0


def follow(client: CellClient, job: dict[str, Any], *, out: TextIO = sys.stdout, stdin: TextIO | None = sys.stdin,
           events_client: CellClient | None = None, what: str | None = None) -> int:  # fmt: skip
    """Follow ``job`` to its end on the event stream, answering prompts from ``stdin``; returns the exit status."""
    job_id = int(job["id"])
    inbox: queue.Queue[tuple[str, dict[str, Any]]] = queue.Queue()
    stop = threading.Event()
    watcher = events_client or client.another()

    def listen() -> None:
        try:
            for kind, data in watcher.events():
                if stop.is_set():
                    return
                if kind in ("job", "prompt") and data.get("job_id") == job_id:
                    inbox.put((kind, data))
                elif kind == "status":
                    inbox.put(("tick", data))
                elif kind == "shutdown":
                    inbox.put(("lost", {"error": "the service is stopping (it said so on its event stream)", "stopping": True}))
                    return
        except ServiceError as err:
            inbox.put(("lost", {"error": str(err)}))
            return
        if not stop.is_set():
            inbox.put(("lost", {"error": f"the event stream of {client.url} ended"}))

    threading.Thread(target=listen, name="cellctl-events", daemon=True).start()
    lines: queue.Queue[str | None] = queue.Queue()
    if stdin is not None:
        threading.Thread(target=_read_lines, args=(stdin, lines), name="cellctl-stdin", daemon=True).start()
    bar = ProgressLine(out, what or job["procedure"].replace("_", " "))
    out.write(f"job {job_id} ({job['procedure']}) started on the cell; Ctrl-C cancels it (the robot stops at once)\n")
    out.flush()
    prompt: dict[str, Any] | None = None
    answered: set[int] = set()  # prompts this terminal answered: no later line goes to them, even before their close comes
    synced = False
    last: dict[str, Any] = {}  # the job as its last event showed it

    def _open(p: dict[str, Any]) -> TextIO | None:
        """Show a prompt that opened; without input (any more) say where it can be answered instead."""
        now = _drop_typed_ahead(lines, out, stdin)
        _show_prompt(out, p, asks=now is not None)
        if now is None:
            _answer_elsewhere(out, client.url, job_id, p)
        return now

    try:
        while True:
            try:
                kind, data = inbox.get(timeout=0.2)
            except queue.Empty:
                kind, data = "", {}
            if kind == "tick" and not synced:
                synced = True
                job = client.job(job_id)  # what happened before the stream was up
                if job["state"] in FINISHED:
                    break
                if job.get("prompt") and job["prompt"]["id"] not in answered and (prompt is None or prompt["id"] != job["prompt"]["id"]):
                    prompt = job["prompt"]
                    bar.clear()
                    stdin = _open(prompt)
            elif kind == "lost":
                try:
                    job = client.job(job_id)
                except ServiceError:
                    job = {**job, **last, "id": job_id}
                    if job["state"] in FINISHED:  # its end came on the stream, just before the service went
                        break
                    bar.clear()
                    service_gone(out, client.url, job, data["error"])
                    return 1
                if job["state"] in FINISHED:
                    break
                if not data.get("stopping"):
                    raise ServiceError(data["error"])
                bar.clear()
                service_gone(out, client.url, job, data["error"])
                return 1
            elif kind == "job":
                last = data
                if data.get("progress"):
                    if prompt is None:
                        bar.update(data["progress"])
                if data["state"] in FINISHED:
                    break
            elif kind == "prompt":
                p = data["prompt"]
                if data["open"]:
                    if p["id"] not in answered:
                        prompt = p
                        bar.clear()
                        stdin = _open(p)
                else:
                    if prompt is not None and prompt["id"] == p["id"]:
                        prompt = None
                    a = data.get("answer")
                    if a is None:
                        out.write("\n    the prompt closed unanswered (the job ended)\n")
                    else:
                        value = f", {a['value']:g}" if a.get("value") is not None else ""
                        out.write(f"\n    answered by {a.get('actor', '?')}: {a.get('action', '?')}{value}\n")
                    out.flush()
            if prompt is not None:
                try:
                    line = lines.get_nowait()
                except queue.Empty:
                    continue
                if line is None:  # no more input: others must answer, and the engineer is told where
                    stdin = None
                    _answer_elsewhere(out, client.url, job_id, prompt)
                    continue
                parsed = _parse(line, prompt)
                if isinstance(parsed, str):
                    out.write(f"    {parsed}\n")
                    _show_prompt(out, prompt)
                    continue
                try:
                    client.answer_prompt(job_id, int(prompt["id"]), parsed[0], parsed[1])
                except ServiceError as err:
                    out.write(f"    not taken: {err}\n")
                else:  # the next line is for the next prompt (piped answers in order), not for this one again
                    answered.add(int(prompt["id"]))
                    prompt = None
    except KeyboardInterrupt:
        bar.clear()
        out.write(f"\ncancelling job {job_id}: the robot is told to stop ...\n")
        out.flush()
        t0 = time.monotonic()
        job = client.cancel_job(job_id)
        out.write(f"job {job_id} {job['state']} after {time.monotonic() - t0:.1f} s\n")
        print_result(job, out)
        return 130
    except BaseException as err:  # a fault of this side: the job must not stay open, its prompts with nobody to answer them
        bar.clear()
        cancel_after_fault(client, job_id, err, out)
        raise
    finally:
        stop.set()
    bar.clear()
    out.write("\n")
    try:
        job = client.job(job_id)
    except ServiceError:  # the service stopped as the job ended: its last event says how
        job = {**job, **last, "id": job_id}
        print_result(job, out)
        service_gone(out, client.url, job, "the service did not answer once the job had ended")
        return exit_status(job) if job["state"] == "done" else 1
    print_result(job, out)
    if job["state"] == "cancelled" and str(job.get("error") or "").startswith(SERVICE_STOPPING):
        service_gone(out, client.url, job, SERVICE_STOPPING)
    return exit_status(job)


def cancel_after_fault(client: CellClient, job_id: int, err: BaseException, out: TextIO) -> None:
    """This terminal stops following job ``job_id`` on an error it does not handle: cancel the job (the robot stops)."""
    out.write(f"\nstopped following job {job_id} on an error ({type(err).__name__}: {err}); cancelling the job, the robot "
              "is told to stop ...\n")  # fmt: skip
    out.flush()
    try:
        job = client.cancel_job(job_id)
    except ServiceError as cancel_err:
        out.write(f"job {job_id} could not be cancelled from here ({cancel_err}): cancel it on the dashboard "
                  f"({client.url}/#/commissioning) or with POST {client.url}/jobs/{job_id}/cancel\n")  # fmt: skip
        out.flush()
        return
    out.write(f"job {job_id} {job['state']}\n")
    print_result(job, out)


def service_gone(out: TextIO, url: str, job: dict[str, Any], why: str) -> None:
    """The service stopped while the job was followed: what is known of the job, and what to do."""
    state = job.get("state", "?")
    if state in FINISHED:
        known = f"it ended {state}" + (f": {job['error']}" if job.get("error") else "")
    else:
        p = job.get("progress") or {}
        at = f" at {p['done']}/{p['total']}" if p.get("total") else ""
        known = (f"it was last seen {state}{at}; a job running when the service stops is cancelled (its record then says "
                 "cancelled, or interrupted if the service was killed)")  # fmt: skip
    out.write(f"\nthe cell service stopped while job {job['id']} ({job.get('procedure', '?')}) ran ({why}): {known}.\n")
    if state != "done":
        out.write("  The robot was told to stop, what the job collected is kept as a partial dataset and the calibration "
                  "set in use is unchanged.\n")  # fmt: skip
    out.write(f"  To go on: start the service again (cellctl serve), read the job's record (GET {url}/jobs/{job['id']})"
              + (", and start the job again.\n" if state != "done" else ".\n"))  # fmt: skip
    out.flush()


def print_plan(plan: dict[str, Any], out: TextIO) -> None:
    """A dry run's plan: how many poses, how long, how the rotations spread, what was dropped."""
    rot = plan["rotation"]
    out.write(f"plan for {plan['procedure']}: {plan['poses']} poses at up to {plan['speed_mm_s']:g} mm/s, "
              f"{plan['speed_deg_s']:g} deg/s; estimated robot time {_clock(plan['estimated_robot_time_s'])}\n")  # fmt: skip
    out.write(f"  rotations between poses: up to {rot['max_pair_angle_deg']:.1f} deg (median {rot['median_pair_angle_deg']:.1f}), "
              f"axis spread {rot['axis_spread']:.2f} (3-D {rot['axis_spread_3d']:.2f}) over {int(rot['pairs'])} pairs\n")  # fmt: skip
    first = plan.get("first_pose")
    if first:
        out.write(f"  first pose: {first['label']} at {first['position_mm']} mm, rx ry rz {first['xyz_fixed_deg']} deg\n")
    if plan["dropped"]:
        out.write(f"  {len(plan['dropped'])} candidate(s) dropped:\n")
        for d in plan["dropped"][:10]:
            out.write(f"    - {d}\n")
    for row in plan.get("pose_list", []):
        out.write(f"  {row['label']:28s} {row['position_mm']} mm  {row['xyz_fixed_deg']} deg\n")
    out.write("nothing moved (dry run)\n")
    out.flush()
