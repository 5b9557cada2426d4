"""Values to and from 16-bit Modbus registers, by the register map.

Bytes inside a register are big-endian (Modbus). A 32-bit value spans two registers in the
configured word order: "big" puts the high word first (ABCD), "little" the low word first (CDAB),
as pymodbus's ``word_order`` does. Pure functions, no I/O.
"""

from __future__ import annotations

import math
import numbers
import operator
import struct
from collections.abc import Mapping, Sequence
from typing import Literal, get_args

from cellctl.plc.register_map import Block, Register, RegType

WordOrder = Literal["big", "little"]
WORD_ORDERS: tuple[str, ...] = get_args(WordOrder)

Value = int | float

_STRUCT = {RegType.UINT16: "H", RegType.INT16: "h", RegType.UINT32: "I", RegType.FLOAT32: "f"}
_INT_RANGE = {
    RegType.UINT16: (0, 0xFFFF),
    RegType.INT16: (-0x8000, 0x7FFF),
    RegType.UINT32: (0, 0xFFFF_FFFF),
}
_FLOAT32_MAX = 3.4028234663852886e38


def _check_order(word_order: str) -> None:
    if word_order not in WORD_ORDERS:
        raise ValueError(f"word order {word_order!r} is not one of {', '.join(WORD_ORDERS)} "
                         "(set [plc] float_word_order)")


def encode_value(reg: Register, value: Value, word_order: WordOrder) -> list[int]:
    """``value`` as ``reg.words`` registers; refuses values the register's type cannot hold."""
    _check_order(word_order)
    if reg.type is RegType.FLOAT32:
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            raise TypeError(f"{reg.name}: {value!r} is not a number")
        f = float(value)
        if not math.isfinite(f) or abs(f) > _FLOAT32_MAX:
            raise ValueError(f"{reg.name}: {f!r} is not a finite float32 value")
        raw = struct.pack(">f", f)
    else:
        try:
            i = operator.index(value)  # type: ignore[arg-type]
        except TypeError:
            raise TypeError(f"{reg.name}: {value!r} is not an integer ({reg.type.label})") from None
        lo, hi = _INT_RANGE[reg.type]
        if not lo <= i <= hi:
            raise ValueError(f"{reg.name}: {i} is outside the {reg.type.label} range {lo}..{hi}")
        raw = struct.pack(">" + _STRUCT[reg.type], i)
    words = [int.from_bytes(raw[k:k + 2], "big") for k in range(0, len(raw), 2)]
    if word_order == "little":
        words.reverse()
    return words


def decode_value(reg: Register, words: Sequence[int], word_order: WordOrder) -> Value:
    """The value held by ``reg.words`` registers."""
    _check_order(word_order)
    if len(words) != reg.words:
        raise ValueError(f"{reg.name}: needs {reg.words} registers, got {len(words)}")
    if not all(0 <= w <= 0xFFFF for w in words):
        raise ValueError(f"{reg.name}: registers must be 0..65535, got {list(words)}")
    ordered = list(words) if word_order == "big" else list(reversed(words))
    raw = b"".join(w.to_bytes(2, "big") for w in ordered)
    (value,) = struct.unpack(">" + _STRUCT[reg.type], raw)
    return value


def encode_block(block: Block, values: Mapping[str, Value], word_order: WordOrder) -> list[int]:
    """The whole block as registers; registers not in ``values`` and reserved addresses are 0."""
    by_name = {r.name: r for r in block.registers}
    unknown = sorted(set(values) - set(by_name))
    if unknown:
        raise KeyError(f"{', '.join(unknown)} not in the {block.name}")
    regs = [0] * block.size
    for name, value in values.items():
        reg = by_name[name]
        off = reg.address - block.start
        regs[off:off + reg.words] = encode_value(reg, value, word_order)
    return regs


def decode_block(block: Block, words: Sequence[int], word_order: WordOrder) -> dict[str, Value]:
    """Every register of ``block`` from the block's registers (``block.size`` words from its start)."""
    if len(words) != block.size:
        raise ValueError(f"{block.name}: needs {block.size} registers, got {len(words)}")
    out: dict[str, Value] = {}
    for reg in block.registers:
        off = reg.address - block.start
        out[reg.name] = decode_value(reg, words[off:off + reg.words], word_order)
    return out
