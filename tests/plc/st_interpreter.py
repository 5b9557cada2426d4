"""A small interpreter for the IEC 61131-3 Structured Text of examples/plc_handshake.st, so tests run the
example's own text scan by scan instead of a transliteration of it.

It knows the subset the example uses: FUNCTION, FUNCTION_BLOCK and PROGRAM with VAR, VAR_INPUT, VAR_OUTPUT,
VAR_IN_OUT (CONSTANT, RETAIN), elementary types, ARRAY[a..b] OF, IF/ELSIF/ELSE, CASE, FOR, assignments, calls
with named or positional arguments, the standard TON and R_TRIG, SHL, SHR, EXPT and the X_TO_Y conversions.
An assignment stores the value in its declared type (a WORD wraps at 65535, a UDINT at 2^32). TIME is seconds
(float); TON reads ``clock()`` in seconds. Anything else is refused with the token it stopped at.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

_TOKEN = re.compile(r"""
    (?P<ws>\s+|\(\*.*?\*\))
  | (?P<time>T\#[0-9A-Za-z_.]+)
  | (?P<based>\d+\#[0-9A-Fa-f_]+)
  | (?P<real>\d+\.\d+(?:[eE][+-]?\d+)?|\d+[eE][+-]?\d+)
  | (?P<int>\d+)
  | (?P<name>[A-Za-z_]\w*)
  | (?P<op>:=|<>|<=|>=|\.\.|[-+*/=<>()\[\],;:.])
""", re.S | re.X)
_WIDTH = {"WORD": (16, False), "UINT": (16, False), "UDINT": (32, False), "DWORD": (32, False),
          "INT": (16, True), "DINT": (32, True), "BYTE": (8, False), "USINT": (8, False)}
_BINARY = [("OR",), ("XOR",), ("AND",), ("=", "<>", "<", ">", "<=", ">="), ("+", "-"), ("*", "/", "MOD")]


def tokenize(text: str) -> list[tuple[str, Any]]:
    out: list[tuple[str, Any]] = []
    pos = 0
    while pos < len(text):
        m = _TOKEN.match(text, pos)
        if m is None:
            raise SyntaxError(f"ST: cannot read {text[pos:pos + 30]!r}")
        pos = m.end()
        kind, raw = m.lastgroup, m.group()
        if kind == "ws":
            continue
        if kind == "time":
            units = {"D": 86400.0, "H": 3600.0, "M": 60.0, "S": 1.0, "MS": 0.001}
            parts = re.findall(r"(\d+(?:\.\d+)?)(MS|D|H|M|S)", raw[2:].upper().replace("_", ""))
            out.append(("lit", sum(float(n) * units[u] for n, u in parts)))
        elif kind == "based":
            base, digits = raw.split("#")
            out.append(("lit", int(digits.replace("_", ""), int(base))))
        elif kind == "real":
            out.append(("lit", float(raw)))
        elif kind == "int":
            out.append(("lit", int(raw)))
        else:
            out.append((kind or "op", raw))
    out.append(("end", None))
    return out


def coerce(type_name: str, value: Any) -> Any:
    """``value`` as the declared type stores it."""
    if type_name == "BOOL":
        return bool(value)
    if type_name in ("REAL", "LREAL", "TIME"):
        return float(value)
    if type_name in _WIDTH:
        bits, signed = _WIDTH[type_name]
        v = int(value) & ((1 << bits) - 1)
        return v - (1 << bits) if signed and v >> (bits - 1) else v
    return value


@dataclass
class Decl:
    kind: str       # VAR, VAR_INPUT, VAR_OUTPUT, VAR_IN_OUT
    type: str       # elementary or POU name; an array's element type
    array: tuple[int, int] | None
    init: Any


@dataclass
class Pou:
    kind: str       # FUNCTION, FUNCTION_BLOCK, PROGRAM
    name: str
    result: str | None
    decls: dict[str, Decl] = field(default_factory=dict)
    body: list[Any] = field(default_factory=list)


class Instance:
    """A function block's or program's memory; its variables are attributes (``inst.Q``, ``inst.ReqId``)."""

    def __init__(self, pou: Pou | None, vars_: dict[str, Any], types: dict[str, str]) -> None:
        object.__setattr__(self, "_pou", pou)
        object.__setattr__(self, "_vars", vars_)
        object.__setattr__(self, "_types", types)

    def __getattr__(self, name: str) -> Any:
        try:
            return self._vars[name]
        except KeyError:
            raise AttributeError(name) from None

    def __setattr__(self, name: str, value: Any) -> None:
        if name not in self._vars:
            raise AttributeError(f"no variable {name}")
        self._vars[name] = coerce(self._types[name], value) if not isinstance(value, list) else value


class Program:
    """The parsed file; ``instance(name)`` makes a program or block instance, ``run(inst)`` runs one scan."""

    def __init__(self, text: str, clock: Callable[[], float]) -> None:
        self.clock = clock
        self._t = tokenize(text)
        self._i = 0
        self.pous: dict[str, Pou] = {}
        while self._peek() != ("end", None):
            pou = self._pou()
            self.pous[pou.name] = pou

    # -- parsing -------------------------------------------------------------------------------------------
    def _peek(self, k: int = 0) -> tuple[str, Any]:
        return self._t[self._i + k]

    def _next(self) -> tuple[str, Any]:
        tok = self._t[self._i]
        self._i += 1
        return tok

    def _is(self, *values: str) -> bool:
        kind, v = self._peek()
        return kind in ("name", "op") and v in values

    def _expect(self, value: str) -> None:
        tok = self._next()
        if tok[1] != value:
            raise SyntaxError(f"ST: expected {value!r}, found {tok[1]!r} (token {self._i})")

    def _name(self) -> str:
        kind, v = self._next()
        if kind != "name":
            raise SyntaxError(f"ST: expected a name, found {v!r} (token {self._i})")
        return str(v)

    def _pou(self) -> Pou:
        kind = self._name()
        if kind not in ("FUNCTION", "FUNCTION_BLOCK", "PROGRAM"):
            raise SyntaxError(f"ST: {kind} is not a POU")
        name = self._name()
        result = None
        if kind == "FUNCTION":
            self._expect(":")
            result = self._name()
        pou = Pou(kind, name, result)
        while self._is("VAR", "VAR_INPUT", "VAR_OUTPUT", "VAR_IN_OUT"):
            section = self._name()
            if self._is("CONSTANT", "RETAIN"):
                self._next()
            while not self._is("END_VAR"):
                names = [self._name()]
                while self._is(","):
                    self._next()
                    names.append(self._name())
                self._expect(":")
                array = None
                if self._is("ARRAY"):
                    self._next()
                    self._expect("[")
                    lo = self._expr()
                    self._expect("..")
                    hi = self._expr()
                    self._expect("]")
                    self._expect("OF")
                    array = (self._const(lo), self._const(hi))
                type_name = self._name()
                init = None
                if self._is(":="):
                    self._next()
                    init = self._const(self._expr())
                self._expect(";")
                for n in names:
                    pou.decls[n] = Decl(section, type_name, array, init)
            self._expect("END_VAR")
        pou.body = self._block({f"END_{kind}"})
        self._expect(f"END_{kind}")
        return pou

    def _const(self, expr: Any) -> Any:
        return self._eval(expr, Instance(None, {}, {}))

    def _block(self, enders: set[str]) -> list[Any]:
        stmts: list[Any] = []
        while not self._is(*enders) and not self._case_label():
            stmts.append(self._statement())
        return stmts

    def _case_label(self) -> bool:
        return self._peek()[0] == "lit" and self._peek(1) == ("op", ":")

    def _statement(self) -> Any:
        if self._is("IF"):
            branches: list[tuple[Any, list[Any]]] = []
            other: list[Any] = []
            while self._is("IF", "ELSIF") and (not branches or self._peek()[1] == "ELSIF"):
                self._next()
                cond = self._expr()
                self._expect("THEN")
                branches.append((cond, self._block({"ELSIF", "ELSE", "END_IF"})))
            if self._is("ELSE"):
                self._next()
                other = self._block({"END_IF"})
            self._expect("END_IF")
            self._expect(";")
            return ("if", branches, other)
        if self._is("CASE"):
            self._next()
            selector = self._expr()
            self._expect("OF")
            cases: list[tuple[list[int], list[Any]]] = []
            while self._case_label():
                labels = [self._next()[1]]
                while self._is(","):
                    self._next()
                    labels.append(self._next()[1])
                self._expect(":")
                cases.append((labels, self._block({"ELSE", "END_CASE"})))
            other = []
            if self._is("ELSE"):
                self._next()
                other = self._block({"END_CASE"})
            self._expect("END_CASE")
            self._expect(";")
            return ("case", selector, cases, other)
        if self._is("FOR"):
            self._next()
            var = self._name()
            self._expect(":=")
            first = self._expr()
            self._expect("TO")
            last = self._expr()
            self._expect("DO")
            body = self._block({"END_FOR"})
            self._expect("END_FOR")
            self._expect(";")
            return ("for", var, first, last, body)
        target = self._postfix(("var", self._name()))
        if target[0] == "call":
            self._expect(";")
            return ("call", target)
        self._expect(":=")
        value = self._expr()
        self._expect(";")
        return ("assign", target, value)

    def _expr(self, level: int = 0) -> Any:
        if level == len(_BINARY):
            return self._unary()
        left = self._expr(level + 1)
        while self._is(*_BINARY[level]):
            op = self._next()[1]
            left = ("bin", op, left, self._expr(level + 1))
        return left

    def _unary(self) -> Any:
        if self._is("NOT", "-"):
            op = self._next()[1]
            return ("un", op, self._unary())
        kind, v = self._next()
        if kind == "lit":
            return ("lit", v)
        if v == "(":
            inner = self._expr()
            self._expect(")")
            return inner
        if v in ("TRUE", "FALSE"):
            return ("lit", v == "TRUE")
        if kind != "name":
            raise SyntaxError(f"ST: unexpected {v!r} (token {self._i})")
        return self._postfix(("var", v))

    def _postfix(self, node: Any) -> Any:
        while True:
            if self._is("["):
                self._next()
                index = self._expr()
                self._expect("]")
                node = ("index", node, index)
            elif self._is("."):
                self._next()
                node = ("member", node, self._name())
            elif self._is("("):
                self._next()
                args: list[tuple[str | None, Any]] = []
                while not self._is(")"):
                    if self._peek()[0] == "name" and self._peek(1) == ("op", ":="):
                        name = self._name()
                        self._next()
                        args.append((name, self._expr()))
                    else:
                        args.append((None, self._expr()))
                    if self._is(","):
                        self._next()
                self._expect(")")
                node = ("call", node, args)
            else:
                return node

    # -- running -------------------------------------------------------------------------------------------
    def instance(self, type_name: str) -> Instance:
        """A fresh instance of a function block or program (or TON, R_TRIG), every variable at its initial value."""
        if type_name == "TON":
            return Instance(None, {"IN": False, "PT": 0.0, "Q": False, "ET": 0.0, "_start": None},
                            {"IN": "BOOL", "PT": "TIME", "Q": "BOOL", "ET": "TIME", "_start": "ANY"})
        if type_name == "R_TRIG":
            return Instance(None, {"CLK": False, "Q": False, "_m": False}, {"CLK": "BOOL", "Q": "BOOL", "_m": "BOOL"})
        pou = self.pous[type_name]
        vars_: dict[str, Any] = {}
        types: dict[str, str] = {}
        for name, d in pou.decls.items():
            types[name] = d.type if d.array is None else "ARRAY"
            if d.array is not None:
                vars_[name] = [self._initial(d.type, d.init) for _ in range(d.array[1] - d.array[0] + 1)]
            else:
                vars_[name] = self._initial(d.type, d.init)
        if pou.result:
            vars_[pou.name], types[pou.name] = coerce(pou.result, 0), pou.result
        return Instance(pou, vars_, types)

    def _initial(self, type_name: str, init: Any) -> Any:
        if type_name in self.pous or type_name in ("TON", "R_TRIG"):
            return self.instance(type_name)
        return coerce(type_name, 0 if init is None else init)

    def run(self, inst: Instance) -> None:
        """One scan of a program (or one call of a block with the inputs already set)."""
        self._exec(inst._pou.body, inst)

    def _call_block(self, target: Instance, args: list[tuple[str | None, Any]], env: Instance) -> None:
        pou = target._pou
        names = [n for n, d in pou.decls.items() if d.kind in ("VAR_INPUT", "VAR_IN_OUT")] if pou else ["IN", "PT"]
        for k, (name, expr) in enumerate(args):
            name = name or names[k]
            if pou is not None and pou.decls[name].kind == "VAR_IN_OUT":
                target._vars[name] = self._eval(expr, env)  # by reference: the caller's array itself
            else:
                setattr(target, name, self._eval(expr, env))
        if pou is not None:
            self._exec(pou.body, target)
        elif "CLK" in target._vars:  # R_TRIG
            target.Q = target.CLK and not target._m
            target._m = target.CLK
        else:  # TON
            now = self.clock()
            if not target.IN:
                target._vars.update(Q=False, ET=0.0, _start=None)
            else:
                if target._start is None:
                    target._vars["_start"] = now
                target.ET = min(now - target._start, target.PT)
                target.Q = target.ET >= target.PT

    def _exec(self, stmts: list[Any], env: Instance) -> None:
        for s in stmts:
            kind = s[0]
            if kind == "assign":
                self._store(s[1], self._eval(s[2], env), env)
            elif kind == "call":
                self._eval(s[1], env)
            elif kind == "if":
                for cond, body in s[1]:
                    if self._eval(cond, env):
                        self._exec(body, env)
                        break
                else:
                    self._exec(s[2], env)
            elif kind == "case":
                value = self._eval(s[1], env)
                for labels, body in s[2]:
                    if value in labels:
                        self._exec(body, env)
                        break
                else:
                    self._exec(s[3], env)
            elif kind == "for":
                _, var, first, last, body = s
                setattr(env, var, self._eval(first, env))
                while getattr(env, var) <= self._eval(last, env):
                    self._exec(body, env)
                    setattr(env, var, getattr(env, var) + 1)

    def _store(self, target: Any, value: Any, env: Instance) -> None:
        if target[0] == "var":
            setattr(env, target[1], value)
        elif target[0] == "index" and target[1][0] == "var":
            name = target[1][1]
            decl = env._pou.decls[name]
            assert decl.array is not None, name
            getattr(env, name)[self._eval(target[2], env) - decl.array[0]] = coerce(decl.type, value)
        else:
            raise SyntaxError(f"ST: cannot assign to {target}")

    def _eval(self, e: Any, env: Instance) -> Any:  # noqa: C901 - one branch per node kind
        kind = e[0]
        if kind == "lit":
            return e[1]
        if kind == "var":
            if e[1] in env._vars:
                return env._vars[e[1]]
            raise NameError(f"ST: {e[1]} is not declared in {env._pou.name if env._pou else 'a constant'}")
        if kind == "index":
            name = e[1][1]
            return getattr(env, name)[self._eval(e[2], env) - env._pou.decls[name].array[0]]
        if kind == "member":
            return getattr(self._eval(e[1], env), e[2])
        if kind == "un":
            v = self._eval(e[2], env)
            return (not v if isinstance(v, bool) else ~v) if e[1] == "NOT" else -v
        if kind == "bin":
            return _binary(e[1], self._eval(e[2], env), self._eval(e[3], env))
        if kind == "call":
            return self._call(e[1], e[2], env)
        raise SyntaxError(f"ST: cannot evaluate {e}")

    def _call(self, callee: Any, args: list[tuple[str | None, Any]], env: Instance) -> Any:
        if callee[0] == "var" and callee[1] in env._vars and isinstance(env._vars[callee[1]], Instance):
            self._call_block(env._vars[callee[1]], args, env)
            return None
        name = callee[1]
        values = [self._eval(a, env) for _, a in args]
        if name == "SHL":
            return values[0] << values[1]
        if name == "SHR":
            return values[0] >> values[1]
        if name == "EXPT":
            return float(values[0]) ** values[1]
        if "_TO_" in name:
            return coerce(name.split("_TO_")[1], values[0])
        fn = self.pous[name]
        call = self.instance(name)
        inputs = [n for n, d in fn.decls.items() if d.kind == "VAR_INPUT"]
        for k, ((arg_name, _), value) in enumerate(zip(args, values, strict=True)):
            setattr(call, arg_name or inputs[k], value)
        self._exec(fn.body, call)
        return call._vars[name]


def _binary(op: str, a: Any, b: Any) -> Any:
    if op in ("AND", "OR", "XOR"):
        if isinstance(a, bool) and isinstance(b, bool):
            return {"AND": a and b, "OR": a or b, "XOR": a != b}[op]
        a, b = int(a), int(b)
        return {"AND": a & b, "OR": a | b, "XOR": a ^ b}[op]
    if op == "/":
        return a / b if isinstance(a, float) or isinstance(b, float) else int(a / b)
    ops: dict[str, Callable[[Any, Any], Any]] = {
        "=": lambda x, y: x == y, "<>": lambda x, y: x != y, "<": lambda x, y: x < y, ">": lambda x, y: x > y,
        "<=": lambda x, y: x <= y, ">=": lambda x, y: x >= y, "+": lambda x, y: x + y, "-": lambda x, y: x - y,
        "*": lambda x, y: x * y, "MOD": lambda x, y: x % y,
    }
    return ops[op](a, b)
