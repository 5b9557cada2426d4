"""The database schema as numbered migrations, tracked in ``PRAGMA user_version``.

Migration N brings a database from version N-1 to N. Each runs in one transaction together with
the user_version update, so a failed migration leaves the database at the previous version.
Never edit a released migration; append a new one (the one exception, a table nothing reads any
more, is told at :data:`V1`). Append one too when the store begins to hold values an older cellctl
cannot read (a new alarm code, a new key), even if no table changes: the older release then refuses
the store (``SchemaTooNew``) on a rollback instead of failing on what it reads.

This module imports nothing of the store but its errors: every repository and the connection
build on it.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Sequence

from cellctl.store.records import INTERRUPTED_REASONS, SchemaTooNew, StoreError

_APPEND_ONLY = """
CREATE TRIGGER {table}_append_only_update BEFORE UPDATE ON {table}
BEGIN SELECT RAISE(ABORT, '{table} is append-only: entries cannot be changed'); END;
CREATE TRIGGER {table}_append_only_delete BEFORE DELETE ON {table}
BEGIN SELECT RAISE(ABORT, '{table} is append-only: entries cannot be deleted'); END;
"""

V1 = (
    """
CREATE TABLE cycles (
    id                  INTEGER PRIMARY KEY AUTOINCREMENT,
    idempotency_scope   TEXT NOT NULL,
    idempotency_key     TEXT NOT NULL,
    recipe              TEXT NOT NULL,
    part_id             TEXT NOT NULL,
    car_id              TEXT,
    source              TEXT NOT NULL,
    actor               TEXT NOT NULL,
    state               TEXT NOT NULL
        CHECK (state IN ('queued', 'running', 'done', 'failed', 'interrupted')),
    current_step        INTEGER NOT NULL DEFAULT 0,
    result_json         TEXT,
    error               TEXT,
    true_error_json     TEXT,
    created_at          TEXT NOT NULL,
    started_at          TEXT,
    finished_at         TEXT,
    install_started_at  TEXT,
    interrupted_step    INTEGER,
    interrupted_at      TEXT
);
CREATE INDEX cycles_by_state ON cycles (state);
CREATE INDEX cycles_by_key ON cycles (idempotency_scope, idempotency_key);

-- Once written, the install marker can never be unset: the no-repeat guarantee does not rely
-- on every code path remembering it.
CREATE TRIGGER cycles_install_marker_is_permanent BEFORE UPDATE OF install_started_at ON cycles
WHEN OLD.install_started_at IS NOT NULL AND NEW.install_started_at IS NOT OLD.install_started_at
BEGIN SELECT RAISE(ABORT, 'the install-started marker of a cycle cannot be changed'); END;

CREATE TABLE cycle_steps (
    id            INTEGER PRIMARY KEY AUTOINCREMENT,
    cycle_id      INTEGER NOT NULL REFERENCES cycles (id),
    step          INTEGER NOT NULL,
    attempt       INTEGER NOT NULL,
    started_at    TEXT NOT NULL,
    finished_at   TEXT,
    duration_s    REAL,
    ok            INTEGER,
    figures_json  TEXT NOT NULL DEFAULT '{}',
    error         TEXT,
    UNIQUE (cycle_id, step, attempt)
);

CREATE TABLE cycle_images (
    id          INTEGER PRIMARY KEY AUTOINCREMENT,
    cycle_id    INTEGER NOT NULL REFERENCES cycles (id),
    step        INTEGER NOT NULL,
    name        TEXT NOT NULL,
    uri         TEXT NOT NULL,
    created_at  TEXT NOT NULL
);

CREATE TABLE idempotency_keys (
    scope          TEXT NOT NULL,
    key            TEXT NOT NULL,
    request_hash   TEXT NOT NULL,
    request_json   TEXT NOT NULL,
    cycle_id       INTEGER REFERENCES cycles (id),
    response_json  TEXT,
    created_at     TEXT NOT NULL,
    completed_at   TEXT,
    PRIMARY KEY (scope, key)
);

CREATE TABLE alarms (
    uid         TEXT PRIMARY KEY,
    code        INTEGER NOT NULL,
    value       INTEGER NOT NULL,
    message     TEXT NOT NULL,
    category    INTEGER NOT NULL,
    severity    INTEGER NOT NULL,
    source      TEXT NOT NULL,
    raised_at   TEXT NOT NULL,
    active      INTEGER NOT NULL,
    condition   INTEGER NOT NULL,
    ack_at      TEXT,
    ack_by      TEXT,
    cleared_at  TEXT,
    reaction    INTEGER,
    cycle_id    INTEGER
);
CREATE INDEX alarms_by_time ON alarms (raised_at);

CREATE TABLE audit_log (
    seq           INTEGER PRIMARY KEY,
    at            TEXT NOT NULL,
    actor         TEXT NOT NULL,
    source        TEXT NOT NULL,
    action        TEXT NOT NULL,
    params_json   TEXT NOT NULL,
    state_before  TEXT,
    state_after   TEXT,
    result        TEXT NOT NULL,
    cycle_id      INTEGER,
    prev_hash     TEXT NOT NULL,
    hash          TEXT NOT NULL
);
"""
    + _APPEND_ONLY.format(table="audit_log")
)
"""Cycles with their steps, images and idempotency keys; alarms; the audit log.

V1 once also created an append-only ``calibrations`` table, a calibration history that nothing in
production wrote or read (the versioned calibration set lives in files:
:mod:`cellctl.calibration.calibration_set`, reported by ``GET /calibration``). It was taken out of
V1 rather than dropped by a new migration: a database created before keeps that table and its
triggers, unused and harmless; no code reads or writes it.
"""

V2_JOBS = """
CREATE TABLE jobs (
    id                INTEGER PRIMARY KEY AUTOINCREMENT,
    procedure         TEXT NOT NULL,
    state             TEXT NOT NULL
        CHECK (state IN ('running', 'computing', 'done', 'refused', 'failed', 'cancelled', 'interrupted')),
    actor             TEXT NOT NULL,
    source            TEXT NOT NULL,
    options_json      TEXT NOT NULL DEFAULT '{}',
    plan_json         TEXT,
    progress_json     TEXT,
    dataset           TEXT,
    result_json       TEXT,
    error             TEXT,
    version_before    INTEGER,
    version_after     INTEGER,
    created_at        TEXT NOT NULL,
    finished_at       TEXT
);
CREATE INDEX jobs_by_state ON jobs (state);
"""
"""Commissioning jobs (:mod:`cellctl.store.jobs`)."""

V3_RETENTION = """
ALTER TABLE cycle_images ADD COLUMN pruned_at TEXT;
ALTER TABLE cycle_images ADD COLUMN pruned_reason TEXT;
CREATE INDEX cycle_images_by_cycle ON cycle_images (cycle_id);
CREATE INDEX cycles_by_created ON cycles (created_at);
"""
"""An image reference says when and why its file was pruned (:mod:`cellctl.store.retention`)."""

V4_SPC = """
CREATE TABLE spc_state (
    id          INTEGER PRIMARY KEY CHECK (id = 1),
    state_json  TEXT NOT NULL,
    updated_at  TEXT NOT NULL,
    history_id  INTEGER
);

CREATE TABLE spc_history (
    id                   INTEGER PRIMARY KEY AUTOINCREMENT,
    recorded_at          TEXT NOT NULL,
    cycle_id             INTEGER,
    calibration_version  TEXT,
    events_json          TEXT NOT NULL DEFAULT '[]',
    excluded             TEXT,
    u_json               TEXT,
    estimate_json        TEXT NOT NULL,
    offset_json          TEXT NOT NULL,
    drifting_json        TEXT NOT NULL DEFAULT '[]'
);
CREATE UNIQUE INDEX spc_history_one_per_cycle ON spc_history (cycle_id) WHERE cycle_id IS NOT NULL;
CREATE INDEX spc_history_by_time ON spc_history (recorded_at);
"""
"""The closed-loop offset (:mod:`cellctl.store.spc`): its latest state (one row) and a history row
per update. A cycle feeds the loop once (the unique index); ``cycle_id`` has no foreign key, the
history's rows go with their cycles in :meth:`cellctl.store.retention.RetentionRows.prune_cycles`."""

V5_IMAGE_DIGEST = """
ALTER TABLE cycle_images ADD COLUMN sha256 TEXT;
ALTER TABLE cycle_images ADD COLUMN size_bytes INTEGER;
CREATE INDEX cycles_by_car ON cycles (car_id);
CREATE INDEX cycles_by_part ON cycles (part_id);
CREATE INDEX audit_log_by_cycle ON audit_log (cycle_id) WHERE cycle_id IS NOT NULL;
CREATE INDEX alarms_by_cycle ON alarms (cycle_id) WHERE cycle_id IS NOT NULL;
"""
"""Traceability: an image reference keeps the SHA-256 and size of the file as written (NULL for
images recorded before); cycles are found by car body and by glass, and a cycle's audit entries
and alarms by its id (``GET /parts``, :mod:`cellctl.store.parts`)."""

V6_MQTT_OUTBOX = """
CREATE TABLE mqtt_outbox (
    seq         INTEGER PRIMARY KEY,
    topic       TEXT NOT NULL,
    payload     TEXT NOT NULL,
    qos         INTEGER NOT NULL,
    retain      INTEGER NOT NULL,
    kind        TEXT NOT NULL,
    created_at  TEXT NOT NULL
);
CREATE INDEX mqtt_outbox_retained ON mqtt_outbox (topic) WHERE retain = 1;

CREATE TABLE mqtt_outbox_state (
    id                          INTEGER PRIMARY KEY CHECK (id = 1),
    last_seq                    INTEGER NOT NULL DEFAULT 0,
    result_hwm                  INTEGER,
    dropped_total               INTEGER NOT NULL DEFAULT 0,
    dropped_results             INTEGER NOT NULL DEFAULT 0,
    unreported_dropped          INTEGER NOT NULL DEFAULT 0,
    unreported_dropped_results  INTEGER NOT NULL DEFAULT 0
);
INSERT INTO mqtt_outbox_state (id) VALUES (1);

CREATE TABLE mqtt_retained (
    topic       TEXT PRIMARY KEY
);
"""
"""Messages for the plant's MQTT broker not yet acknowledged by it (:mod:`cellctl.store.outbox`,
:mod:`cellctl.mqtt`): a broker outage or a restart of the service loses none up to the configured
bound. ``mqtt_outbox_state`` holds the message sequence (``seq`` never goes back), the last cycle
whose result was queued (NULL until publication is first enabled) and the drop counters;
``mqtt_retained`` the retained topics the cell has set and not cleared."""

V7_SPC_PER_RECIPE = """
CREATE TABLE spc_state_by_recipe (
    recipe      TEXT NOT NULL PRIMARY KEY,
    state_json  TEXT NOT NULL,
    updated_at  TEXT NOT NULL,
    history_id  INTEGER
);
INSERT INTO spc_state_by_recipe (recipe, state_json, updated_at, history_id)
    SELECT '', state_json, updated_at, history_id FROM spc_state;
DROP TABLE spc_state;
ALTER TABLE spc_state_by_recipe RENAME TO spc_state;
ALTER TABLE spc_history ADD COLUMN recipe TEXT;
CREATE INDEX spc_history_by_recipe ON spc_history (recipe, id);
"""
"""One closed loop per recipe (each recipe's install pose is taught on its own, so each has its own
offset): ``spc_state`` keeps a row per recipe, ``''`` for the cell's first recipe (as the calibration
set keeps the first recipe's teaching in its common parts) and the loop of before this migration;
a history row names its recipe (NULL: the first)."""


def _sql_text(text: str) -> str:
    return "'" + text.replace("'", "''") + "'"


V8_INTERRUPTED_REASONS = f"""
UPDATE cycles SET error = CASE WHEN started_at IS NULL THEN {_sql_text(INTERRUPTED_REASONS[0])}
    WHEN install_started_at IS NULL THEN {_sql_text(INTERRUPTED_REASONS[1])} ELSE {_sql_text(INTERRUPTED_REASONS[2])} END
WHERE state = 'interrupted' AND error IS NULL;
"""
"""Cycles interrupted under a cellctl that gave no reason get the one recovery now gives (request it
again, or check the glass by hand). The version also marks what older releases cannot read: alarm
1703 (record write failed) and the closed loops kept under their recipe's name."""


def cut_off_at(found: str) -> str:
    """SQL for when the cycle of the ``cycles`` row was cut off, as far as its record shows: the newest of its steps'
    ``started_at`` and ``finished_at`` and its images' ``created_at`` not after ``found`` (an SQL expression: when
    the service found it cut off), else its ``started_at``, else its ``created_at``; never after ``found``.
    :data:`V9_INTERRUPTED_CUT_OFF` is built with it: change it only together with a new migration."""

    def newest(column: str, table: str) -> str:
        return f"COALESCE((SELECT MAX({column}) FROM {table} WHERE cycle_id = cycles.id AND {column} <= {found}), '')"

    evidence = ", ".join(newest(c, t) for c, t in (("started_at", "cycle_steps"), ("finished_at", "cycle_steps"),
                                                    ("created_at", "cycle_images")))  # fmt: skip
    return f"MIN({found}, COALESCE(NULLIF(MAX({evidence}), ''), cycles.started_at, cycles.created_at))"


V9_INTERRUPTED_CUT_OFF = f"""
ALTER TABLE cycles ADD COLUMN interrupted_found_at TEXT;
UPDATE cycles SET interrupted_found_at = interrupted_at, interrupted_at = {cut_off_at("cycles.interrupted_at")}
WHERE interrupted_at IS NOT NULL;
"""
"""A cycle the service died in keeps two times: ``interrupted_at``, when it was cut off (its last step or image), and
``interrupted_found_at``, when the next start found it (what ``interrupted_at`` held before). Cycles interrupted
before this version get both from what they recorded; a cycle resumed after it counts only what came before."""

V10_END_STAMP = """
ALTER TABLE cycles ADD COLUMN ended_at TEXT;
UPDATE cycles SET ended_at = COALESCE(finished_at, interrupted_found_at) WHERE state IN ('done', 'failed', 'interrupted');
CREATE INDEX cycles_by_ended ON cycles (ended_at);
CREATE TABLE cycle_end_mark (
    id        INTEGER PRIMARY KEY CHECK (id = 1),
    ended_at  TEXT
);
INSERT INTO cycle_end_mark (id, ended_at) SELECT 1, MAX(ended_at) FROM cycles;
"""
"""The time window of ``GET /parts`` runs on ``ended_at``, when the store closed a cycle's record, which never goes back
when the wall clock steps back (:func:`cellctl.store.cycles.end_stamp`); ``finished_at`` and ``interrupted_found_at``
keep the wall clock's time. ``cycle_end_mark`` (one row) keeps the latest end stamp, retention's deletions aside (before
any cycle ended, the bound an export applied less 1 us: the floor of the first end stamp).
Cycles ended before this version get the time the window ran on before; the upgrade raises the floor to its own clock
(an earlier release's export bounds went up to its clock: :func:`cellctl.store.upgrade.migrate_keeping_a_copy`)."""

MIGRATIONS: Sequence[str] = (V1, V2_JOBS, V3_RETENTION, V4_SPC, V5_IMAGE_DIGEST, V6_MQTT_OUTBOX, V7_SPC_PER_RECIPE,
                             V8_INTERRUPTED_REASONS, V9_INTERRUPTED_CUT_OFF, V10_END_STAMP)
"""``MIGRATIONS[i]`` brings the database from version i to i + 1."""

NAME_THE_FIRST_RECIPES_LOOP = (
    """INSERT INTO spc_state (recipe, state_json, updated_at, history_id)
    SELECT :name, state_json, updated_at, history_id FROM spc_state WHERE recipe = ''
    ON CONFLICT (recipe) DO UPDATE SET state_json = excluded.state_json, updated_at = excluded.updated_at,
    history_id = excluded.history_id WHERE excluded.updated_at > spc_state.updated_at""",
    "DELETE FROM spc_state WHERE recipe = ''",
    "UPDATE spc_history SET recipe = :name WHERE recipe IS NULL",
)
"""The one data migration that needs the configuration, so it runs when the cell's loops load
(:meth:`cellctl.store.spc.SpcRows.spc_states` given ``first_recipe``), not at open: the loop that
:data:`V7_SPC_PER_RECIPE` and the cell before it kept unnamed (``''``, history NULL, "the first
recipe's") takes the name ``:name`` of the recipe configured first, once; from then on every loop
is kept under its recipe's name, so reordering or renaming ``[[process.recipes]]`` moves no loop.
Of two rows for one recipe (an older cellctl ran again after it) the later one stays."""


def schema_version(conn: sqlite3.Connection) -> int:
    return int(conn.execute("PRAGMA user_version").fetchone()[0])


def migrate(conn: sqlite3.Connection, migrations: Sequence[str] = MIGRATIONS) -> tuple[int, int]:
    """Apply the pending migrations; returns (version before, version after).

    The connection must be in autocommit mode (``isolation_level=None``).
    """
    before = schema_version(conn)
    latest = len(migrations)
    if before > latest:
        raise SchemaTooNew(
            f"the database is at schema version {before}, newer than this cellctl knows ({latest}): "
            "it was written by a later release: install that release again, or put back the store as it was before "
            "that upgrade"
        )
    for version in range(before + 1, latest + 1):
        try:
            conn.executescript(
                f"BEGIN IMMEDIATE;\n{migrations[version - 1]}\nPRAGMA user_version = {version};\nCOMMIT;"
            )
        except sqlite3.Error as err:
            if conn.in_transaction:
                conn.execute("ROLLBACK")
            raise StoreError(f"migration to schema version {version} failed: {err}") from err
    return before, latest
