"""Settings of the store ([store]), the alarms and device watchdog ([alarms]) and the PackML
state machine ([packml]).

The field names match the constructors they feed: ``WatchdogSettings(**cfg.alarms.watchdog.model_dump())``,
``CellStore.open(cfg.store.path, synchronous=..., busy_timeout_s=...)``; PackML state and mode
names are the enum names in lower case (``PackMLState[name.upper()]``).
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator, model_validator

from cellctl.config.types import Finite, StrictModel

PackMLStateName = Literal[
    "clearing", "stopped", "starting", "idle", "suspended", "execute", "stopping", "aborting", "aborted",
    "holding", "held", "unholding", "suspending", "unsuspending", "resetting", "completing", "complete",
]  # fmt: skip


class StoreConfig(StrictModel):
    """The SQLite database (WAL mode). A relative path is relative to the service's working directory."""

    path: str = "var/cellctl.db"
    synchronous: Literal["FULL", "NORMAL"] = "FULL"  # FULL: a commit also survives a power cut
    busy_timeout_s: Finite = Field(5.0, gt=0, le=60)

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
