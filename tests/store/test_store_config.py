"""The [store], [alarms] and [packml] config models feed the store, watchdog and machine unchanged."""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ValidationError

from cellctl.cell.packml import PackMLMachine
from cellctl.cell.tags import PackMLState, UnitMode
from cellctl.cell.watchdog import WatchdogSettings
from cellctl.config.store import AlarmsConfig, PackMLConfig, StoreConfig, WatchdogConfig
from cellctl.store import CellStore


def test_defaults_build_the_parts(tmp_path: Path) -> None:
    store_cfg = StoreConfig(path=str(tmp_path / "cell.db"), synchronous="NORMAL")
    with CellStore.open(store_cfg.path, synchronous=store_cfg.synchronous, busy_timeout_s=store_cfg.busy_timeout_s) as s:
        assert s.info().synchronous == "NORMAL"
    wd = WatchdogSettings(**AlarmsConfig().watchdog.model_dump())
    assert (wd.period_s, wd.timeout_s, wd.miss_threshold) == (1.0, 0.5, 3)
    pk = PackMLConfig(mode_change_states=("stopped",), initial_state="stopped", initial_mode="maintenance")
    m = PackMLMachine(
        initial_state=PackMLState[pk.initial_state.upper()],
        initial_mode=UnitMode[pk.initial_mode.upper()],
        mode_change_states={PackMLState[n.upper()] for n in pk.mode_change_states},
    )
    assert (m.state, m.mode, m.mode_change_states) == (PackMLState.STOPPED, UnitMode.MAINTENANCE, {PackMLState.STOPPED})


def test_bad_settings_name_the_problem() -> None:
    with pytest.raises(ValidationError, match="timeout_s = 2 exceeds period_s = 1"):
        WatchdogConfig(period_s=1.0, timeout_s=2.0)
    with pytest.raises(ValidationError, match="must name a database file"):
        StoreConfig(path=":memory:")
    with pytest.raises(ValidationError, match="at least one state"):
        PackMLConfig(mode_change_states=())
    with pytest.raises(ValidationError, match="initial_state"):
        PackMLConfig(initial_state="execute")  # type: ignore[arg-type]
    with pytest.raises(ValidationError, match="mode_change_states"):
        PackMLConfig(mode_change_states=("idel",))  # type: ignore[arg-type]
    with pytest.raises(ValidationError, match="Extra inputs"):
        AlarmsConfig(watchdgo={})  # type: ignore[call-arg]
