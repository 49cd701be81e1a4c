"""A requirement's formula: a small signal temporal logic, parsed into a tree.

Grammar (``and`` binds tighter than ``or``, which binds tighter than ``implies``, right-associative)::

    formula  := disj ("implies" formula)?
    disj     := conj ("or" conj)*
    conj     := unary ("and" unary)*
    unary    := "not" unary
              | ("always" | "eventually") interval? unary
              | "(" formula ")"
              | NAME ("<" | "<=" | ">" | ">=") NUMBER
    interval := "[" NUMBER "," (NUMBER | "end") "]"          seconds from the instant it is read at

``always`` without an interval is ``always[0, end]``. A ``NAME`` is a signal of what the run
recorded (``signals``). Every error is a ``FormulaError`` of one line.
"""

import math
import re
from dataclasses import dataclass

END = math.inf  #: ``end``: the interval reaches the end of the run


class FormulaError(ValueError):
    """A formula that does not parse; the message says where."""


@dataclass(frozen=True)
class Atom:
    signal: str
    op: str  #: ``<``, ``<=``, ``>``, ``>=``
    value: float


@dataclass(frozen=True)
class Not:
    arg: "Formula"


@dataclass(frozen=True)
class And:
    left: "Formula"
    right: "Formula"


@dataclass(frozen=True)
class Or:
    left: "Formula"
    right: "Formula"


@dataclass(frozen=True)
class Implies:
    left: "Formula"
    right: "Formula"


@dataclass(frozen=True)
class Always:
    start_s: float
    end_s: float  #: ``END`` for the end of the run
    arg: "Formula"


@dataclass(frozen=True)
class Eventually:
    start_s: float
    end_s: float
    arg: "Formula"


Formula = Atom | Not | And | Or | Implies | Always | Eventually

_TOKEN = re.compile(
    r"\s*(?:(<=|>=|<|>|\(|\)|\[|\]|,)"  # operators and brackets
    r"|([A-Za-z_][A-Za-z0-9_]*)"  # names and keywords
    r"|([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?))"  # numbers
)
KEYWORDS = frozenset({"and", "or", "not", "implies", "always", "eventually", "end"})


def _tokens(text: str) -> list[str]:
    out, at = [], 0
    text = text.rstrip()
    while at < len(text):
        m = _TOKEN.match(text, at)
        if m is None or m.end() == at:
            rest = text[at:].lstrip()  # (the character named is the first that cannot be read)
            raise FormulaError(f"cannot read {rest[:20]!r} (at character {len(text) - len(rest) + 1})")
        out.append(m.group(0).strip())
        at = m.end()
    return out


class _Parser:
    def __init__(self, text: str):
        self.tokens = _tokens(text)
        self.at = 0

    def peek(self) -> str | None:
        return self.tokens[self.at] if self.at < len(self.tokens) else None

    def take(self, literal: str | None = None, what: str | None = None) -> str:
        """The next token: ``literal`` itself if given, else anything (``what``, for the line)."""
        tok = self.peek()
        wanted = repr(literal) if literal is not None else what or "more"
        if tok is None:
            raise FormulaError(f"it ends where {wanted} was expected")
        if literal is not None and tok != literal:
            raise FormulaError(f"{wanted} expected, found {tok!r}")
        self.at += 1
        return tok

    def formula(self) -> Formula:
        left = self.disj()
        if self.peek() == "implies":
            self.take()
            return Implies(left, self.formula())
        return left

    def disj(self) -> Formula:
        node = self.conj()
        while self.peek() == "or":
            self.take()
            node = Or(node, self.conj())
        return node

    def conj(self) -> Formula:
        node = self.unary()
        while self.peek() == "and":
            self.take()
            node = And(node, self.unary())
        return node

    def number(self) -> float:
        tok = self.take(what="a number")
        try:
            return float(tok)
        except ValueError:
            raise FormulaError(f"a number expected, found {tok!r}") from None

    def interval(self) -> tuple[float, float]:
        if self.peek() != "[":
            return 0.0, END
        self.take("[")
        start = self.number()
        self.take(",")
        end = END if self.peek() == "end" else None
        if end is None:
            end = self.number()
        else:
            self.take("end")
        self.take("]")
        if not (0 <= start < end):
            raise FormulaError(f"the interval [{start:g}, {end:g}] is empty or starts before 0")
        return start, end

    def unary(self) -> Formula:
        tok = self.peek()
        if tok == "not":
            self.take()
            return Not(self.unary())
        if tok in ("always", "eventually"):
            self.take()
            start, end = self.interval()
            arg = self.unary()
            return Always(start, end, arg) if tok == "always" else Eventually(start, end, arg)
        if tok == "(":
            self.take()
            node = self.formula()
            self.take(")")
            return node
        name = self.take(what="a signal")
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name) or name in KEYWORDS:
            raise FormulaError(f"a signal expected, found {name!r}")
        op = self.take(what="a comparison")
        if op not in ("<", "<=", ">", ">="):
            raise FormulaError(f"<, <=, > or >= expected after {name}, found {op!r}")
        return Atom(name, op, self.number())


def parse(text: str) -> Formula:
    """The tree of ``text``; ``FormulaError`` (one line) if it is not a formula."""
    p = _Parser(text)
    if p.peek() is None:
        raise FormulaError("the formula is empty")
    node = p.formula()
    if p.peek() is not None:
        raise FormulaError(f"unexpected {p.peek()!r} after a whole formula")
    return node


def signals_of(node: Formula) -> set[str]:
    """The signals a formula reads."""
    if isinstance(node, Atom):
        return {node.signal}
    if isinstance(node, Not | Always | Eventually):
        return signals_of(node.arg)
    return signals_of(node.left) | signals_of(node.right)


def first_start_s(node: Formula) -> float:
    """The earliest instant a formula read at 0 looks at [s] (the largest of its temporal starts
    along each path's first operator): an interval past the run's end reads nothing."""
    if isinstance(node, Always | Eventually):
        return node.start_s + first_start_s(node.arg)
    if isinstance(node, Not):
        return first_start_s(node.arg)
    if isinstance(node, Atom):
        return 0.0
    return min(first_start_s(node.left), first_start_s(node.right))
