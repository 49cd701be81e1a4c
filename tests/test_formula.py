"""A requirement's formula read back (``specs.formula``): any tree, written with every operator in
parentheses or with only those precedence needs and any spacing, parses to itself; what a formula
first looks at is the earliest sample its semantics read; every malformed text is one line naming
what is wrong."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from swarm_sitl.specs.formula import (
    END,
    KEYWORDS,
    Always,
    And,
    Atom,
    Eventually,
    FormulaError,
    Implies,
    Not,
    Or,
    first_start_s,
    parse,
    signals_of,
)
from swarm_sitl.specs.robustness import robustness

pytestmark = pytest.mark.unit

_NAMES = st.from_regex(r"[A-Za-z_][A-Za-z0-9_]{0,6}", fullmatch=True).filter(lambda s: s not in KEYWORDS)
_VALUES = st.floats(allow_nan=False, allow_infinity=False)
_STARTS = st.one_of(st.integers(0, 5).map(float), st.floats(0, 1e3, allow_subnormal=False))


def _window(start: float, extra: float | None) -> tuple[float, float]:
    return start, END if extra is None else start + extra


_WINDOWS = st.builds(
    _window, _STARTS, st.one_of(st.none(), st.floats(1e-3, 1e3), st.integers(1, 5).map(float))
).filter(lambda w: w[0] < w[1])


def _trees(names=_NAMES, values=_VALUES, windows=_WINDOWS) -> st.SearchStrategy:
    def extend(inner):
        return st.one_of(
            st.builds(Not, inner),
            st.builds(And, inner, inner),
            st.builds(Or, inner, inner),
            st.builds(Implies, inner, inner),
            st.builds(lambda w, f: Always(*w, f), windows, inner),
            st.builds(lambda w, f: Eventually(*w, f), windows, inner),
        )

    atoms = st.builds(Atom, names, st.sampled_from(["<", "<=", ">", ">="]), values)
    return st.recursive(atoms, extend, max_leaves=8)


#: how tightly each form binds (the grammar's levels): implies, or, and, then the unary forms
_LEVEL = {Implies: 1, Or: 2, And: 3}
#: the level each operand must have, left and right: ``or`` and ``and`` chain to the left,
#: ``implies`` to the right
_OPERANDS = {Implies: (2, 1), Or: (2, 3), And: (3, 4)}


def _tokens(node, loose: bool, need: int, draw) -> list[str]:
    """``node`` as tokens: with ``loose``, parentheses only where a level below ``need`` needs
    them, else around every operator; ``always`` over ``[0, end]`` written with or without it."""
    level = _LEVEL.get(type(node), 4)
    if isinstance(node, Atom):
        body = [node.signal, node.op, repr(node.value)]
    elif isinstance(node, Not):
        body = ["not", *_tokens(node.arg, loose, 4, draw)]
    elif isinstance(node, Always | Eventually):
        word = "always" if isinstance(node, Always) else "eventually"
        bare = node.start_s == 0 and node.end_s == END and draw(st.booleans())
        end = "end" if node.end_s == END else repr(node.end_s)
        window = [] if bare else ["[", repr(node.start_s), ",", end, "]"]
        body = [word, *window, *_tokens(node.arg, loose, 4, draw)]
    else:
        left, right = _OPERANDS[type(node)]
        op = {Implies: "implies", Or: "or", And: "and"}[type(node)]
        body = [*_tokens(node.left, loose, left, draw), op, *_tokens(node.right, loose, right, draw)]
    wrap = (level < need) if loose else not isinstance(node, Atom) or draw(st.booleans())
    return ["(", *body, ")"] if wrap else body


def _wordlike(tok: str) -> bool:
    return tok[-1].isalnum() or tok[-1] in "._"


def _joined(tokens: list[str], draw) -> str:
    """Tokens with any spacing: none where the tokens stay apart without it."""
    text = draw(st.sampled_from(["", " ", "\n  "]))
    for a, b in zip(tokens, [*tokens[1:], None], strict=True):
        text += a
        if b is not None:
            apart = _wordlike(a) and (_wordlike(b) or b[0] in "+-")
            text += draw(st.sampled_from([" ", "  ", "\t", "\n"] if apart else ["", " ", "\n"]))
    return text + draw(st.sampled_from(["", " ", "\n"]))


@given(_trees(), st.booleans(), st.data())
def test_any_formula_written_any_way_parses_to_itself(tree, loose, data):
    text = _joined(_tokens(tree, loose, 1, data.draw), data.draw)
    assert parse(text) == tree, text


@given(_trees())
def test_the_signals_of_a_formula_are_the_names_in_its_atoms(tree):
    def atoms(node):
        if isinstance(node, Atom):
            return [node]
        if isinstance(node, Not | Always | Eventually):
            return atoms(node.arg)
        return atoms(node.left) + atoms(node.right)

    assert signals_of(tree) == {a.signal for a in atoms(tree)}


def _read(node, k: int, n: int) -> set[int]:
    """The samples (of ``n``, 1 s apart) the semantics read for ``node`` at sample ``k``."""
    if isinstance(node, Atom):
        return {k} if k < n else set()
    if isinstance(node, Not):
        return _read(node.arg, k, n)
    if isinstance(node, Always | Eventually):
        last = n - 1 if node.end_s == END else k + int(node.end_s)
        reach = range(k + int(node.start_s), min(last, n - 1) + 1)
        return set().union(*[_read(node.arg, j, n) for j in reach])
    return _read(node.left, k, n) | _read(node.right, k, n)


_SMALL = _trees(
    st.sampled_from(["x", "y"]),
    st.integers(-2, 2).map(float),
    st.builds(_window, st.integers(0, 4).map(float), st.one_of(st.none(), st.integers(1, 3).map(float))),
)


@given(_SMALL, st.lists(st.integers(-3, 3).map(float), min_size=16, max_size=16), st.data())
def test_a_formula_first_looks_at_the_first_sample_it_reads_and_none_before_it_matters(tree, xs, data):
    """On 16 samples 1 s apart, long enough for any window drawn: the first instant is the
    earliest sample the semantics read, and a trace changed anywhere before it has the same
    robustness at 0."""
    n = len(xs)
    first = first_start_s(tree)
    assert first == min(_read(tree, 0, n))
    x = np.array(xs)
    y = x[::-1].copy()
    before = robustness(tree, {"x": x, "y": y}, 1.0)[0]
    k = data.draw(st.integers(0, max(0, int(first) - 1)))
    if k < first:
        x2, y2 = x.copy(), y.copy()
        x2[k], y2[k] = data.draw(_VALUES.filter(lambda v: abs(v) < 1e6)), -x2[k]
        assert robustness(tree, {"x": x2, "y": y2}, 1.0)[0] == before


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("", "the formula is empty"),
        ("  \n ", "the formula is empty"),
        ("x < 1)", "unexpected ')' after a whole formula"),
        ("x < 1 y > 2", "unexpected 'y' after a whole formula"),
        ("and < 1", "a signal expected, found 'and'"),
        ("always[0, 1] end < 1", "a signal expected, found 'end'"),
        ("3 < 1", "a signal expected, found '3'"),
        ("x and y", "<, <=, > or >= expected after x, found 'and'"),
        ("x", "it ends where a comparison was expected"),
        ("x <", "it ends where a number was expected"),
        ("x < y", "a number expected, found 'y'"),
        ("always[1 2] (x < 1)", "',' expected, found '2'"),
        ("always[1, 2 (x < 1)", "']' expected, found '('"),
        ("always[1, end", "it ends where ']' was expected"),
        ("always[, 2] (x < 1)", "a number expected, found ','"),
        ("always[-1, 2] (x < 1)", "the interval [-1, 2] is empty or starts before 0"),
        ("eventually[2, 2] (x < 1)", "the interval [2, 2] is empty or starts before 0"),
        ("(x < 1", "it ends where ')' was expected"),
        ("x < 1 or", "it ends where a signal was expected"),
        ("x < 1 implies", "it ends where a signal was expected"),
        ("x == 1", "cannot read '== 1' (at character 3)"),
        ("x <= 1 and y ! 2", "cannot read '! 2' (at character 14)"),
        ("x < 1 and " + "y" * 30 + " ?" + "z" * 30, "cannot read '?" + "z" * 19 + "' (at character 42)"),
        ("  x < 1 & y > 2", "cannot read '& y > 2' (at character 9)"),
    ],
)
def test_a_formula_that_does_not_parse_is_one_line_saying_what_is_wrong(text, says):
    with pytest.raises(FormulaError) as e:
        parse(text)
    assert str(e.value) == says or str(e.value).startswith(says), str(e.value)
    assert "\n" not in str(e.value)


def test_a_bare_always_is_over_the_whole_run_and_end_reaches_the_end():
    assert parse("always x < 1") == Always(0.0, END, Atom("x", "<", 1.0))
    assert parse("eventually[2.5, end] x >= -1e-3") == Eventually(2.5, math.inf, Atom("x", ">=", -1e-3))
