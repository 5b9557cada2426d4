"""``python -m abb_robot.bench [--seconds 60]``: the EGM loop's rate and reply latency against the fake.

Starts the fake controller in its own process, connects :class:`abb_robot.AbbRobot`, starts an
EGM session through the line protocol and streams a moving target (a 1 mm, 0.5 Hz sine along x)
for the given time, then stops the session and prints:

- the rate: EgmRobot datagrams the controller sent and replies it received, per second;
- missed cycles: cycles whose reply had not arrived when the next cycle was due, and sequence
  gaps seen by the peer;
- the reply latency: p50, p99 and max, as the peer sees it (datagram received to reply sent)
  and as the controller sees it (datagram sent to reply received, both processes and the
  loopback included).

Target: 250 Hz, no missed cycle, p99 under 1 ms. ``--rt-priority N`` runs both EGM loops (the
peer's child process and the fake's EGM thread) with SCHED_FIFO at priority N (needs root or
CAP_SYS_NICE), which is how a cell PC that does other work should run the peer.
"""

from __future__ import annotations

import argparse
import asyncio
import gc
import json
import math
import os
import socket
import subprocess
import sys
import tempfile
import time

from abb_robot.client import AbbRobot, AbbRobotSettings
from abb_robot.egm.peer_types import latency_percentiles_ms
from cellctl.ports import CartesianPose, MotionInterrupted


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _start_fake(egm_port: int, stats_file: str, seed: int, rt_priority: int | None) -> tuple[subprocess.Popen[str], int]:
    cmd = [
        sys.executable, "-m", "abb_robot.fake", "--rapid-port", "0", "--egm-port", str(egm_port),
        "--stats-file", stats_file, "--seed", str(seed), "--egm-comm-timeout-s", "1.0",
    ]
    if rt_priority is not None:
        cmd += ["--rt-priority", str(rt_priority)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    deadline = time.monotonic() + 15.0
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if line.startswith("READY"):
            fields = dict(f.split("=", 1) for f in line.split()[1:])
            return proc, int(fields["rapid_port"])
        if not line and proc.poll() is not None:
            break
    proc.kill()
    raise RuntimeError("the fake controller did not report READY")


async def run(seconds: float, seed: int, rt_priority: int | None = None) -> dict[str, object]:
    egm_port = _free_udp_port()
    fd, stats_file = tempfile.mkstemp(prefix="abb-egm-stats-", suffix=".json")
    os.close(fd)
    os.unlink(stats_file)
    proc, rapid_port = _start_fake(egm_port, stats_file, seed, rt_priority)
    robot = AbbRobot(
        AbbRobotSettings(
            host="127.0.0.1", rapid_port=rapid_port, egm_port=egm_port, egm_bind_host="127.0.0.1",
            egm_rt_priority=rt_priority,
        ),
        name="bench robot",
    )
    try:
        await robot.connect(timeout_s=5.0)
        start = await robot.read_pose(timeout_s=2.0)
        peer = robot.egm
        assert peer is not None
        session = await robot.start_egm_session(band_mm=0.01, band_deg=0.01, cond_s=seconds + 30.0, timeout_s=2.0)
        t0 = time.monotonic()
        x0, y0, z0 = start.position_mm
        while (elapsed := time.monotonic() - t0) < seconds:
            dx = 1.0 * math.sin(2.0 * math.pi * 0.5 * elapsed)
            peer.set_reference(
                CartesianPose((x0 + dx, y0, z0), start.quaternion_wxyz), tolerance_mm=1.0, tolerance_rad=0.01
            )
            await asyncio.sleep(0.01)
        await robot.stop(timeout_s=2.0)
        try:
            await asyncio.wait_for(session, 3.0)
        except MotionInterrupted:
            pass  # the session ends with ERR 140 (stopped), as asked
        peer_stats = peer.stats()
        deadline = time.monotonic() + 5.0
        while not os.path.exists(stats_file) and time.monotonic() < deadline:
            await asyncio.sleep(0.05)
        await asyncio.sleep(0.1)
        with open(stats_file, encoding="utf-8") as fh:
            fake_stats = json.load(fh)
    finally:
        await robot.close()
        proc.terminate()
        try:
            proc.wait(5.0)
        except subprocess.TimeoutExpired:
            proc.kill()
        if os.path.exists(stats_file):
            os.unlink(stats_file)
    p50, p99, pmax = latency_percentiles_ms(peer_stats.reply_latency_s)
    return {
        "seconds": seconds,
        "rt_priority": rt_priority,
        "controller": fake_stats,
        "peer": {
            "received": peer_stats.received,
            "replied": peer_stats.replied,
            "lost": peer_stats.lost,
            "gap_events": peer_stats.gap_events,
            "superseded": peer_stats.superseded,
            "duplicates": peer_stats.duplicates,
            "stale": peer_stats.stale,
            "max_interarrival_ms": peer_stats.max_interarrival_s * 1000.0,
            "latency_ms": {"p50": p50, "p99": p99, "max": pmax},
        },
    }


def report(r: dict[str, object]) -> str:
    c = r["controller"]
    p = r["peer"]
    assert isinstance(c, dict) and isinstance(p, dict)
    dur = float(c["duration_s"])
    sent, replies = int(c["sent"]), int(c["replies"])
    rtt = c["rtt_ms"]
    lat = p["latency_ms"]
    rate = replies / dur if dur > 0 else 0.0
    met = rate >= 249.0 and c["missed_cycles"] == 0 and p["lost"] == 0 and (rtt["p99"] or 1e9) < 1.0
    rt = r.get("rt_priority")
    lines = [
        f"EGM loop against the fake controller (own process), {dur:.1f} s session, "
        f"{'SCHED_FIFO ' + str(rt) if rt is not None else 'normal scheduling'}",
        f"  controller: sent {sent} EgmRobot ({sent / dur:.1f} Hz), received {replies} replies ({rate:.1f} Hz)",
        f"  missed cycles (no reply before the next cycle): {c['missed_cycles']}, of which "
        f"{c['missed_while_late']} while the controller's own 4 ms loop woke late; its tick overruns: "
        f"{c['tick_overruns']}",
        f"  peer: received {p['received']}, replied {p['replied']}, sequence gaps {p['gap_events']} "
        f"(lost {p['lost']}), superseded {p['superseded']}, longest gap {p['max_interarrival_ms']:.2f} ms",
        f"  reply latency at the peer (receive -> send):        p50 {lat['p50']:.3f} ms  p99 {lat['p99']:.3f} ms  "
        f"max {lat['max']:.3f} ms",
        f"  reply latency at the controller (send -> reply in): p50 {rtt['p50']:.3f} ms  p99 {rtt['p99']:.3f} ms  "
        f"max {rtt['max']:.3f} ms",
        f"  target 250 Hz, no missed cycle, p99 < 1 ms: {'met' if met else 'NOT met'}",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m abb_robot.bench", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=60.0, help="length of the EGM session (default 60)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--rt-priority", type=int, default=None,
                    help="run both EGM threads (peer and fake) with SCHED_FIFO at this priority (needs root)")
    ap.add_argument("--json", action="store_true", help="print the raw figures as JSON as well")
    args = ap.parse_args(argv)
    if not (0 < args.seconds <= 3600):
        ap.error("--seconds must be in (0, 3600]")
    gc.freeze()  # what is loaded now stays: keep full collections short during the loop
    result = asyncio.run(run(args.seconds, args.seed, args.rt_priority))
    print(report(result))
    if args.json:
        print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
