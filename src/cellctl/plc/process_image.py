"""The two halves of the PLC process image: what the PLC wrote, and what the cell publishes.

``PlcInputs`` is a decoded snapshot of the PLC block, handed to waiters through ``InputFeed``.
``CellImage`` holds every value of the cell block; it refuses names outside the cell block, so the
cell cannot write the PLC's registers by mistake.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields

from cellctl.plc.codec import Value, WordOrder, encode_block, encode_value
from cellctl.plc.register_map import CELL_BLOCK, MAP_VERSION, PLC_BLOCK, Register


@dataclass(frozen=True)
class PlcInputs:
    """One read of the PLC block (field names are the PLC block's register names)."""

    plc_heartbeat: int = 0
    cntrl_cmd: int = 0
    cmd_change_request: int = 0
    unit_mode_request: int = 0
    unit_mode_change_request: int = 0
    recipe_id: int = 0
    part_id: int = 0
    cycle_req_id: int = 0
    cycle_request: int = 0
    car_body_id: int = 0

    @classmethod
    def from_decoded(cls, values: Mapping[str, Value]) -> PlcInputs:
        return cls(**{f.name: int(values[f.name]) for f in fields(cls)})


_missing = {r.name for r in PLC_BLOCK.registers} ^ {f.name for f in fields(PlcInputs)}
if _missing:  # the dataclass must mirror the map exactly
    raise RuntimeError(f"PlcInputs and the PLC block disagree on: {', '.join(sorted(_missing))}")


class InputFeed:
    """The latest ``PlcInputs``; handshakes wait here for the condition they need."""

    def __init__(self) -> None:
        self._latest = PlcInputs()
        self._changed = asyncio.Condition()

    @property
    def latest(self) -> PlcInputs:
        return self._latest

    async def publish(self, inputs: PlcInputs) -> None:
        async with self._changed:
            self._latest = inputs
            self._changed.notify_all()

    async def wait_for(self, predicate: Callable[[PlcInputs], bool]) -> PlcInputs:
        """The first snapshot (the current one included) for which ``predicate`` holds."""
        async with self._changed:
            await self._changed.wait_for(lambda: predicate(self._latest))
            return self._latest


class CellImage:
    """Every value of the cell block, encoded on demand in the configured word order."""

    def __init__(self) -> None:
        self._regs: dict[str, Register] = {r.name: r for r in CELL_BLOCK.registers}
        self._values: dict[str, Value] = {name: 0 for name in self._regs}
        self._values["map_version_major"], self._values["map_version_minor"] = MAP_VERSION

    def _register(self, name: str) -> Register:
        reg = self._regs.get(name)
        if reg is None:
            if any(r.name == name for r in PLC_BLOCK.registers):
                raise KeyError(f"{name} is in the PLC block; the cell never writes the PLC block")
            raise KeyError(f"no register {name!r} in the cell block")
        return reg

    def update(self, **values: Value | Mapping[str, bool]) -> None:
        """Set several values at once (all or none). A flags word takes {bit name: bool} to merge."""
        staged: dict[str, Value] = {}
        for name, value in values.items():
            reg = self._register(name)
            if isinstance(value, Mapping):
                if not reg.bits:
                    raise TypeError(f"{name} is not a flags word; give it a number")
                word = int(self._values[name])
                by_name = {b.name: b.index for b in reg.bits}
                for bit, on in value.items():
                    if bit not in by_name:
                        raise KeyError(f"{name} has no bit {bit!r}; it has {', '.join(by_name)}")
                    word = word | (1 << by_name[bit]) if on else word & ~(1 << by_name[bit])
                value = word
            encode_value(reg, value, "big")  # refuse what the register cannot hold, here and now
            staged[name] = value
        self._values.update(staged)

    def value(self, name: str) -> Value:
        return self._values[self._register(name).name]

    def flag(self, word: str, bit: str) -> bool:
        reg = self._register(word)
        index = next((b.index for b in reg.bits if b.name == bit), None)
        if index is None:
            raise KeyError(f"{word} has no bit {bit!r}")
        return bool(int(self._values[word]) >> index & 1)

    def registers(self, word_order: WordOrder) -> list[int]:
        return encode_block(CELL_BLOCK, self._values, word_order)
