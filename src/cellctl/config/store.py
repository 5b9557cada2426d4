"""Settings of the store ([store]), the alarms and device watchdog ([alarms]) and the PackML
state machine ([packml]).

The field names match the constructors they feed: ``WatchdogSettings(**cfg.alarms.watchdog.model_dump())``,
``CellStore.open(cfg.store.path, synchronous=..., busy_timeout_s=...)``; PackML state and mode
names are the enum names in lower case (``PackMLState[name.upper()]``).
"""

from __future__ import annotations

from typing import Literal, Union

from pydantic import Field, ValidationInfo, field_validator, model_validator

from cellctl.config.types import Finite, StrictModel

PackMLStateName = Literal[
    "clearing", "stopped", "starting", "idle", "suspended", "execute", "stopping", "aborting", "aborted",
    "holding", "held", "unholding", "suspending", "unsuspending", "resetting", "completing", "complete",
]  # fmt: skip


Days = Union[Literal["forever"], Finite]
"""A retention period: a number of days (> 0), or ``"forever"``."""


def _days(name: str, v: float | str) -> float | str:
    if v != "forever" and not (isinstance(v, (int, float)) and v > 0):
        raise ValueError(f"{name} must be a number of days above 0, or \"forever\"")
    return v


def days_or_none(v: float | str) -> float | None:
    """The days of a :data:`Days` field, None for ``"forever"``."""
    return None if v == "forever" else float(v)


class RetentionConfig(StrictModel):
    """What the store keeps, and the disk-space alarms ([store.retention]).

    Images go first: the oldest are deleted while they are older than ``images_days`` or all
    images together exceed ``images_max_gb`` (an image of a queued or running cycle is never
    deleted); the image's record stays and says when and why it was pruned. Cycle records
    (with their steps, image references and idempotency keys) go after ``cycles_days``, alarm
    records after ``alarms_days`` once acknowledged (an alarm of a kept cycle record stays with it,
    so ``alarms_days`` below ``cycles_days`` never empties a part record's alarms). The audit log
    is never pruned: it is append-only and hash-chained (the database refuses deletes), it records
    who commanded what, and it is small beside the images; the disk-space alarms guard it like
    everything else.
    """

    enabled: bool = True  # false: nothing is pruned (the disk-space check and /status figures still run)
    images_days: Finite = Field(30.0, gt=0)
    images_max_gb: Finite = Field(20.0, gt=0)
    cycles_days: Days = 365.0
    alarms_days: Days = "forever"
    period_s: Finite = Field(300.0, gt=0, le=86_400)  # a pass this often, and after every finished cycle
    disk_check_period_s: Finite = Field(30.0, gt=0, le=3_600)
    disk_warn_free_gb: Finite = Field(5.0, ge=0)  # alarm 1701 (warning) below this free space
    disk_stop_free_gb: Finite = Field(1.0, ge=0)  # alarm 1702 (Hold) below this: production stops before writes fail

    @field_validator("cycles_days", "alarms_days")
    @classmethod
    def _days_ok(cls, v: float | str, info: ValidationInfo) -> float | str:
        return _days(info.field_name or "days", v)

    @model_validator(mode="after")
    def _consistent(self) -> "RetentionConfig":
        cycles = days_or_none(self.cycles_days)
        if cycles is not None and self.images_days > cycles:
            raise ValueError(
                f"images_days = {self.images_days:g} exceeds cycles_days = {cycles:g}: an image would outlive its "
                "cycle record; keep cycle records at least as long as images"
            )
        if self.disk_stop_free_gb > self.disk_warn_free_gb:
            raise ValueError(
                f"disk_stop_free_gb = {self.disk_stop_free_gb:g} exceeds disk_warn_free_gb = {self.disk_warn_free_gb:g}: "
                "the warning must come before the stop"
            )
        return self


class StoreConfig(StrictModel):
    """The SQLite database (WAL mode). A relative path is relative to the service's working directory.

    The cycle images are written beside it, in ``<its folder>/images``.
    """

    path: str = "var/cellctl.db"
    synchronous: Literal["FULL", "NORMAL"] = "FULL"  # FULL: a commit also survives a power cut
    busy_timeout_s: Finite = Field(5.0, gt=0, le=60)
    retention: RetentionConfig = RetentionConfig()

    @field_validator("path")
    @classmethod
    def _a_file(cls, v: str) -> str:
        if not v.strip() or v.strip() == ":memory:":
            raise ValueError("must name a database file (crash recovery needs one), e.g. 'var/cellctl.db'")
        return v


class WatchdogConfig(StrictModel):
    """How every device is pinged."""

    period_s: Finite = Field(1.0, gt=0)
    timeout_s: Finite = Field(0.5, gt=0)
    miss_threshold: int = Field(3, ge=1, le=100)

    @model_validator(mode="after")
    def _timeout_within_period(self) -> "WatchdogConfig":
        if self.timeout_s > self.period_s:
            raise ValueError(
                f"timeout_s = {self.timeout_s:g} exceeds period_s = {self.period_s:g}: a ping must end "
                "before the next is due; lower timeout_s or raise period_s"
            )
        return self


class AlarmsConfig(StrictModel):
    history: int = Field(200, ge=1, le=100_000)  # finished alarms kept in memory (all go to the store)
    watchdog: WatchdogConfig = WatchdogConfig()


class PackMLConfig(StrictModel):
    """The state machine's start and where unit modes may change."""

    initial_state: Literal["aborted", "stopped"] = "aborted"
    initial_mode: Literal["production", "maintenance", "manual"] = "production"
    mode_change_states: tuple[PackMLStateName, ...] = ("stopped", "idle", "aborted")

    @field_validator("mode_change_states")
    @classmethod
    def _not_empty(cls, v: tuple[str, ...]) -> tuple[str, ...]:
        if not v:
            raise ValueError("must list at least one state, e.g. [\"stopped\", \"idle\", \"aborted\"]")
        return v
