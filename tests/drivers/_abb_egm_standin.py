"""A stand-in for the robot controller, in a process of its own: ``python _abb_egm_standin.py --egm PORT ...``.

It answers cellctl's RAPID line protocol by hand as CellctlServer.mod does (HELLO, TOOL, WOBJ, SPEED, ZONE,
STATE, PING, STOP, BYE, STREAM) on a TCP port of 127.0.0.1 (printed as ``ready <port>``). On ``STREAM 1``
it sends an EgmRobot every 4 ms (encoded by hand, :mod:`_abb_egm_wire`) to the sensor's UDP port: seqno
from 0, ``header.tm`` = tm0 + 4 * seqno ms, the TCP moving 0.1 mm a cycle along x from 500 mm. It logs
each datagram it sends as a JSON line (``seq``, ``tm``, ``x``): the truth a test scores against.

Faults a UDP path can produce: ``--dup N`` sends datagram N twice; ``--late-dup N:K`` sends datagram N
again right after datagram K; ``--udp-port P`` sends to port P instead (a wrong UDPUC remote port);
``--src IP`` sends from that address (NAT, another interface).
"""

from __future__ import annotations

import argparse
import json
import socket
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from _abb_egm_wire import MCI_STOPPED, egm_robot  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--egm", type=int, required=True)
ap.add_argument("--udp-port", type=int, default=None)
ap.add_argument("--src", default="127.0.0.1")
ap.add_argument("--dup", type=int, default=None)
ap.add_argument("--late-dup", default=None)
ap.add_argument("--log", required=True)
ap.add_argument("--tm0", type=int, default=123_456_000)
a = ap.parse_args()

late = tuple(int(v) for v in a.late_dup.split(":")) if a.late_dup else None
stop = threading.Event()
sender: threading.Thread | None = None
log = open(a.log, "a", buffering=1)  # noqa: SIM115 - open for the process's life


def stream() -> None:
    u = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    u.bind((a.src, 0))
    to = ("127.0.0.1", a.udp_port if a.udp_port is not None else a.egm)
    sent: dict[int, bytes] = {}
    seq, t0 = 0, time.monotonic()
    while not stop.is_set():
        tm, x = a.tm0 + 4 * seq, 500.0 + 0.1 * seq
        data = sent[seq] = egm_robot(seq, tm, x, mci=MCI_STOPPED, wall_s=time.time())
        u.sendto(data, to)
        log.write(json.dumps({"seq": seq, "tm": tm, "x": x}) + "\n")
        if a.dup == seq:
            u.sendto(data, to)
        if late is not None and late[1] == seq:
            u.sendto(sent[late[0]], to)
        seq += 1
        time.sleep(max(0.0, t0 + 0.004 * seq - time.monotonic()))
    u.close()


def serve(conn: socket.socket) -> None:
    global sender
    buf = b""
    while True:
        chunk = conn.recv(4096)
        if not chunk:
            return
        buf += chunk
        while b"\n" in buf:
            raw, buf = buf.split(b"\n", 1)
            rid, verb, *args = raw.decode().split()
            verb = verb.upper()
            if verb == "HELLO":
                out = "OK 1 IRB_7600-325/3.1 6.15.00"
            elif verb == "PING":
                out = "PONG"
            elif verb in ("TOOL", "WOBJ"):
                out = f"OK {args[0]}"
            elif verb == "SPEED":
                out = f"OK {float(args[0]):.1f} {float(args[1]):.1f}"
            elif verb == "ZONE":
                out = f"OK {float(args[0]):.1f}"
            elif verb == "STATE":
                out = "OK 1 0"
            elif verb in ("STREAM", "STOP", "BYE"):
                on = verb == "STREAM" and args[0] == "1"
                stop.set()
                if sender is not None:
                    sender.join()
                if on:
                    stop.clear()
                    sender = threading.Thread(target=stream, daemon=True)
                    sender.start()
                out = "OK" if verb == "BYE" else f"OK {1 if on else 0}"
            else:
                out = "ERR 100 unknown verb"
            conn.sendall(f"{rid} {out}\n".encode())
            if verb == "BYE":
                return


server = socket.socket()
server.bind(("127.0.0.1", 0))
server.listen(1)
print(f"ready {server.getsockname()[1]}", flush=True)
while True:
    client, _ = server.accept()
    try:
        serve(client)
    except OSError:
        pass
    client.close()
