"""The MQTT outbox in the store: messages the broker has not acknowledged yet, durable and bounded.

Migration 6 of :mod:`cellctl.store.schema`. The publisher (:mod:`cellctl.mqtt`) sends the rows in
``seq`` order and deletes each only after the broker acknowledged it, so an outage or a restart
of the service loses nothing up to the bound. The store keeps plain values: a message is a topic,
a JSON body (or None: an empty retained message, which clears the topic) and its flags.

- ``seq``: one sequence for every message of the cell, never reused; :meth:`OutboxRows.outbox_enqueue`
  writes it into the body as ``seq``, and :meth:`OutboxRows.outbox_next_seq` hands one out for a
  message sent without a row (the connection's status and will).
- Retained topics hold a value, not a history: a new retained message replaces one still pending
  for the same topic (not counted as a drop).
- The bound: when ``max_messages`` rows are pending, the oldest row that is not a cycle result
  (kind ``result``) goes first; a result pushes out the oldest result only when nothing else is
  left, and a message that is not a result never pushes out a result (it is dropped itself).
  The row the publisher is sending (``in_flight``, waiting for its PUBACK) is never dropped, so a
  dropped message is one the broker never got. Every drop is counted (in total and results alone, and how many the plant has not been told
  of yet) and returned to the caller. Superseded and dropped messages leave gaps in ``seq``.
- Results: ``result_hwm`` is the last cycle whose result was queued, written in the same
  transaction as the result's rows; a cycle at or below it is never queued twice.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from cellctl.store.connection import Database, need, to_json, ts

RESULT_KIND = "result"
"""The kind of a cycle's result message, dropped only when nothing else is left to drop."""


@dataclass(frozen=True)
class OutboxMessage:
    """A message to queue: ``body`` None is an empty (clearing) retained message."""

    topic: str
    body: Mapping[str, Any] | None
    kind: str
    retain: bool = False
    qos: int = 1


@dataclass(frozen=True)
class OutboxRow:
    """A queued message as the publisher sends it (``payload`` is the JSON text, '' to clear)."""

    seq: int
    topic: str
    payload: str
    qos: int
    retain: bool
    kind: str


@dataclass(frozen=True)
class DroppedMessage:
    """A message the bound pushed out before the broker had it."""

    seq: int
    topic: str
    kind: str


@dataclass(frozen=True)
class Enqueued:
    """What :meth:`OutboxRows.outbox_enqueue` did: the rows' seqs (empty when the result was queued
    before), what the bound dropped, and how many rows are pending now."""

    seqs: tuple[int, ...]
    dropped: tuple[DroppedMessage, ...]
    pending: int


@dataclass(frozen=True)
class OutboxCounts:
    """Pending rows and the drop counters (all drops ever; those not yet reported to the plant)."""

    pending: int
    last_seq: int
    result_hwm: int | None
    dropped_total: int
    dropped_results: int
    unreported_dropped: int
    unreported_dropped_results: int


class OutboxRows(Database):
    """The MQTT outbox methods of :class:`cellctl.store.db.CellStore`."""

    def outbox_enqueue(
        self,
        messages: Sequence[OutboxMessage],
        *,
        max_messages: int,
        result_of_cycle: int | None = None,
        in_flight: int | None = None,
    ) -> Enqueued:
        """Queue ``messages`` in one transaction, in order, each with the next ``seq`` in its body.

        With ``result_of_cycle`` they are that cycle's result: queued only if the cycle is above
        the results' high-water mark, which moves to it in the same transaction. The bound never
        drops row ``in_flight`` (the one being sent).
        """
        if max_messages < len(messages) + 1:
            raise ValueError(f"max_messages ({max_messages}) must exceed the messages queued at once ({len(messages)})")
        for m in messages:
            need("topic", m.topic)
        now = ts(self._clock())
        dropped: list[DroppedMessage] = []
        seqs: list[int] = []
        with self._tx() as c:
            last_seq, hwm = c.execute("SELECT last_seq, result_hwm FROM mqtt_outbox_state WHERE id = 1").fetchone()
            if result_of_cycle is not None and hwm is not None and result_of_cycle <= hwm:
                return Enqueued((), (), self._pending(c))
            for m in messages:
                if m.retain:  # a retained topic holds a value: the pending older one is superseded
                    c.execute("DELETE FROM mqtt_outbox WHERE retain = 1 AND topic = ?", (m.topic,))
                last_seq += 1
                if not self._make_room(c, max_messages, m.kind == RESULT_KIND, dropped, in_flight):
                    dropped.append(DroppedMessage(last_seq, m.topic, m.kind))  # only results are queued: not this one
                    continue
                payload = "" if m.body is None else to_json(f"MQTT message for {m.topic}", {**m.body, "seq": last_seq})
                c.execute(
                    "INSERT INTO mqtt_outbox (seq, topic, payload, qos, retain, kind, created_at) VALUES (?, ?, ?, ?, ?, ?, ?)",
                    (last_seq, m.topic, payload, int(m.qos), int(m.retain), m.kind, now),
                )
                if m.retain and m.body is None:
                    c.execute("DELETE FROM mqtt_retained WHERE topic = ?", (m.topic,))
                elif m.retain:
                    c.execute("INSERT OR IGNORE INTO mqtt_retained (topic) VALUES (?)", (m.topic,))
                seqs.append(last_seq)
            results = sum(1 for d in dropped if d.kind == RESULT_KIND)
            c.execute(
                "UPDATE mqtt_outbox_state SET last_seq = ?, result_hwm = CASE WHEN ? IS NULL THEN result_hwm ELSE ? END, "
                "dropped_total = dropped_total + ?, dropped_results = dropped_results + ?, "
                "unreported_dropped = unreported_dropped + ?, unreported_dropped_results = unreported_dropped_results + ? "
                "WHERE id = 1",
                (last_seq, result_of_cycle, result_of_cycle, len(dropped), results, len(dropped), results),
            )
            pending = self._pending(c)
        return Enqueued(tuple(seqs), tuple(dropped), pending)

    def outbox_next_seq(self) -> int:
        """A new ``seq`` for a message sent without a row (the status and the will of a connection)."""
        with self._tx() as c:
            c.execute("UPDATE mqtt_outbox_state SET last_seq = last_seq + 1 WHERE id = 1")
            return int(c.execute("SELECT last_seq FROM mqtt_outbox_state WHERE id = 1").fetchone()[0])

    def outbox_pending(self, *, limit: int = 100) -> list[OutboxRow]:
        """The oldest pending rows, in ``seq`` order."""
        rows = self._conn.execute(
            "SELECT seq, topic, payload, qos, retain, kind FROM mqtt_outbox ORDER BY seq LIMIT ?", (int(limit),)
        ).fetchall()
        return [OutboxRow(int(r[0]), r[1], r[2], int(r[3]), bool(r[4]), r[5]) for r in rows]

    def outbox_delete(self, seq: int) -> int:
        """The broker acknowledged row ``seq``: forget it. Returns how many rows are still pending."""
        with self._tx() as c:
            c.execute("DELETE FROM mqtt_outbox WHERE seq = ?", (int(seq),))
            return self._pending(c)

    def outbox_counts(self) -> OutboxCounts:
        """Pending rows, the last seq, the results' high-water mark and the drop counters."""
        r = self._conn.execute(
            "SELECT last_seq, result_hwm, dropped_total, dropped_results, unreported_dropped, "
            "unreported_dropped_results FROM mqtt_outbox_state WHERE id = 1"
        ).fetchone()
        return OutboxCounts(self._pending(self._conn), int(r[0]), None if r[1] is None else int(r[1]), *map(int, r[2:]))

    def outbox_drops_reported(self, dropped: int, dropped_results: int) -> None:
        """The plant was told of ``dropped`` drops (``dropped_results`` of them results)."""
        with self._tx() as c:
            c.execute(
                "UPDATE mqtt_outbox_state SET unreported_dropped = MAX(0, unreported_dropped - ?), "
                "unreported_dropped_results = MAX(0, unreported_dropped_results - ?) WHERE id = 1",
                (int(dropped), int(dropped_results)),
            )

    def outbox_start_results(self) -> int:
        """The results' high-water mark, set to the newest cycle the first time (history is not published)."""
        with self._tx() as c:
            c.execute(
                "UPDATE mqtt_outbox_state SET result_hwm = (SELECT COALESCE(MAX(id), 0) FROM cycles) "
                "WHERE id = 1 AND result_hwm IS NULL"
            )
            return int(c.execute("SELECT result_hwm FROM mqtt_outbox_state WHERE id = 1").fetchone()[0])

    def outbox_result_backlog(self, *, limit: int = 100) -> list[int]:
        """Cycles above the high-water mark that have finished, in id order, up to the first that has not."""
        hwm = self._conn.execute("SELECT COALESCE(result_hwm, 0) FROM mqtt_outbox_state WHERE id = 1").fetchone()[0]
        ids: list[int] = []
        for cid, state in self._conn.execute(
            "SELECT id, state FROM cycles WHERE id > ? ORDER BY id LIMIT ?", (int(hwm), int(limit))
        ):
            if state in ("queued", "running"):
                break
            ids.append(int(cid))
        return ids

    def outbox_retained_topics(self) -> list[str]:
        """The retained topics the cell has set and not cleared (to clear those that no longer hold)."""
        return [r[0] for r in self._conn.execute("SELECT topic FROM mqtt_retained ORDER BY topic")]

    # -- internals ----------------------------------------------------------------------------

    @staticmethod
    def _pending(c: Any) -> int:
        return int(c.execute("SELECT COUNT(*) FROM mqtt_outbox").fetchone()[0])

    @staticmethod
    def _make_room(
        c: Any, max_messages: int, for_result: bool, dropped: list[DroppedMessage], in_flight: int | None = None
    ) -> bool:
        """Drop the oldest rows until one more fits: non-results first, results only to make room for a result,
        never row ``in_flight``. False: nothing of that is left (the new message is dropped instead)."""
        while OutboxRows._pending(c) >= max_messages:
            row = c.execute(
                "SELECT seq, topic, kind FROM mqtt_outbox WHERE (kind != ? OR ?) AND seq != ? "
                "ORDER BY kind = ?, seq LIMIT 1",
                (RESULT_KIND, int(for_result), -1 if in_flight is None else int(in_flight), RESULT_KIND),
            ).fetchone()
            if row is None:
                return False
            c.execute("DELETE FROM mqtt_outbox WHERE seq = ?", (row[0],))
            dropped.append(DroppedMessage(int(row[0]), row[1], row[2]))
        return True
