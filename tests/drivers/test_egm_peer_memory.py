"""The EGM peer's memory stays flat over a long session (the OS's VmRSS is the peer).

A upb message that is cleared and parsed into again keeps what it held in its arena: the peer that parsed
every datagram into one reused EgmRobot grew ~190 bytes a datagram (47 kB per second of EGM at 250 Hz, for the
life of the peer), the served simulated cell ~6 MB per 100 cycles. Run in a child process so that nothing else
of the test session moves its resident memory.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DATAGRAMS = 200_000  # 13 min of EGM at 250 Hz

CHILD = f"""
import sys, time
sys.path[:0] = [{str(ROOT / "drivers")!r}, {str(ROOT / "src")!r}]
from abb_robot.egm.peer_core import LatencySink, PeerCore, StreamSink, reference_vector, sample_robot_message

def rss_mb():
    return int(next(l for l in open("/proc/self/status") if l.startswith("VmRSS")).split()[1]) / 1024

msg = sample_robot_message()
core = PeerCore(controller_host=None, receive_timeout_s=1.0, latency=LatencySink(4), stream=StreamSink(4))
core.apply_reference(reference_vector(1, ((1.0, 2.0, 3.0), (1.0, 0.0, 0.0, 0.0)), 0.1, 0.01))
datagrams = []
for seq in range(1000):
    msg.header.seqno = seq
    msg.header.tm = 4 * seq
    datagrams.append(msg.SerializeToString())
for k in range(1000):  # warm up: allocator pools, first calls
    core.accept(datagrams[k], ("127.0.0.1", 1), time.perf_counter())
before = rss_mb()
for k in range(1000, 1000 + {DATAGRAMS}):
    msg.header.seqno, msg.header.tm = k, 4 * k  # one session: seqno and tm go on
    assert core.accept(msg.SerializeToString(), ("127.0.0.1", 1), time.perf_counter())
    core.reply_bytes(time.perf_counter())
print(rss_mb() - before)
"""


def test_a_long_egm_session_does_not_grow_the_peers_memory() -> None:
    out = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    grew_mb = float(out.stdout.strip().splitlines()[-1])
    # the reused message grew 61 MB over these datagrams; fresh ones leave the process where it was
    assert grew_mb < 4.0, f"the EGM peer's resident memory grew {grew_mb:.1f} MB over {DATAGRAMS} datagrams"
