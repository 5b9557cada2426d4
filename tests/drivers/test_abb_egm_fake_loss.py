"""The fake controller's seeded EGM loss: which datagrams drop is fixed by the seed, not by the host's timing."""

from __future__ import annotations

import socket
import threading

import numpy as np

from _abb_testkit import LOOPBACK, free_udp_port, start_fake
from abb_robot.egm import egm_pb2 as pb
from abb_robot.fake import EgmDynamics
from abb_robot.fake.egm_robot import EgmSessionParams, EgmSessionStats

LAST_SEQNO = 120  # the scripted sensor stops the session once it has seen this far


def _sensor(sock: socket.socket, reply_every: int, seen: threading.Event, done: threading.Event) -> None:
    """A scripted sensor: answers every ``reply_every``-th EgmRobot (by seqno) with the pose it reported,
    numbering its EgmSensor replies 0, 1, 2, ... as the driver's peer does."""
    reply_seq = 0
    while not done.is_set():
        try:
            data, addr = sock.recvfrom(4096)
        except socket.timeout:
            continue
        msg = pb.EgmRobot.FromString(data)
        if msg.header.seqno >= LAST_SEQNO:
            seen.set()
        if msg.header.seqno % reply_every:
            continue
        out = pb.EgmSensor()
        out.header.seqno, out.header.mtype = reply_seq, pb.EgmHeader.MSGTYPE_CORRECTION
        out.planned.cartesian.CopyFrom(msg.feedBack.cartesian)
        sock.sendto(out.SerializeToString(), addr)
        reply_seq += 1


def _session_with_replies_every(reply_every: int) -> EgmSessionStats:
    """One session of a fresh fake (seed 5, 20 % loss each way) against a sensor replying at that pace."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind((LOOPBACK, free_udp_port()))
    sock.settimeout(0.1)
    fake = start_fake(egm_sensor_port=sock.getsockname()[1], seed=5, egm_loss_out=0.2, egm_loss_in=0.2,
                      egm=EgmDynamics(comm_timeout_s=2.0))
    seen, ended, done = threading.Event(), threading.Event(), threading.Event()
    sensor = threading.Thread(target=_sensor, args=(sock, reply_every, seen, done), daemon=True)
    sensor.start()
    try:
        assert fake.egm is not None
        fake.egm.begin(EgmSessionParams(band_mm=0.01, band_deg=0.01, cond_s=60.0), lambda _: ended.set())
        assert seen.wait(10.0), "the scripted sensor never saw the session get far enough"
        fake.egm.request_stop()
        assert ended.wait(5.0)
        stats = fake.egm.last_stats
        assert stats is not None and stats.end == "stopped" and stats.sent > LAST_SEQNO
        return stats
    finally:
        done.set()
        sensor.join(timeout=5.0)
        sock.close()
        fake.stop_thread()


def test_the_seed_fixes_the_drops_whatever_the_reply_pace() -> None:
    every = _session_with_replies_every(1)  # a reply after each datagram: as many draws in as out
    third = _session_with_replies_every(3)  # a third as many replies: another interleaving of the two ways
    assert every.replies > 2 * third.replies > 0
    common = min(every.sent, third.sent)
    out_every = [s for s in every.dropped_seqnos if s < common]
    assert out_every == [s for s in third.dropped_seqnos if s < common] and len(out_every) >= 10
    # Each reply is judged by its own seqno: those both sessions read drop alike.
    read_both = set(every.reply_seqnos) & set(third.reply_seqnos)
    in_every = [r for r in every.dropped_reply_seqnos if r in read_both]
    assert in_every == [r for r in third.dropped_reply_seqnos if r in read_both] and len(in_every) >= 3
    # ... and by the documented rule (session 0 of each fake: seed, direction, session, seqno).
    rule = [s for s in range(every.sent) if np.random.default_rng([5, 0, 0, s]).random() < 0.2]
    assert every.dropped_seqnos == rule
