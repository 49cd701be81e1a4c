"""A campaign's table (``campaigns/table.py``) over random rows: what is written reads back as it
was, float for float (a missing metric as NaN, counts as integers, texts as texts); a table
appended to by several writers, as a resumed campaign's is, has one header and every row in the
order it came; the sorted table is the same rows ordered by their values and seeds, written whole
in place of the old one; and two runs are the same run exactly when their values agree to 12
decimals and their seeds agree."""

import math

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from swarm_sitl.campaigns.point import METRICS
from swarm_sitl.campaigns.table import TABLE, TableWriter, columns, read_rows, row_key, write_sorted

pytestmark = pytest.mark.unit

KEYS = ["link.loss", "delay_s"]
REQS = ["formation", "quiet"]
_value = st.one_of(
    st.floats(allow_nan=False, allow_infinity=False, width=64), st.sampled_from([0.0, -0.0, 1e-13])
)
_metric = st.one_of(st.just(math.nan), st.floats(allow_nan=False, allow_infinity=False))
_text = st.text(st.characters(blacklist_categories=["Cs"], blacklist_characters="\x00"), max_size=20)


@st.composite
def _row(draw) -> dict:
    row: dict = {k: draw(_value) for k in KEYS}
    row["seed"] = draw(st.integers(0, 2**31))
    row["refined"] = draw(st.integers(0, 1))
    for m in METRICS:
        row[m] = draw(st.integers(0, 1) if m == "passed" else (_text if m == "failure" else _metric))
    for r in REQS:
        row[f"spec.{r}"] = draw(_metric)
    row["config"] = draw(st.sampled_from(["", "points/p0001.yaml", "points/a b.yaml"]))
    return row


def _same(a: dict, b: dict) -> bool:
    """Equal cell for cell, NaN equal to NaN, -0.0 told from 0.0."""
    if a.keys() != b.keys():
        return False
    for k, v in a.items():
        w = b[k]
        if isinstance(v, float) and math.isnan(v):
            if not (isinstance(w, float) and math.isnan(w)):
                return False
        elif (
            v != w
            or type(v) is not type(w)
            or (isinstance(v, float) and math.copysign(1, v) != math.copysign(1, w))
        ):
            return False
    return True


@settings(max_examples=60, deadline=None)
@given(batches=st.lists(st.lists(_row(), max_size=4), min_size=1, max_size=3))
def test_rows_written_by_one_writer_after_another_read_back_as_they_were_in_order(batches, tmp_path_factory):
    path = tmp_path_factory.mktemp("table") / TABLE
    for batch in batches:  # each writer a resumed campaign's: the header once, rows appended
        w = TableWriter(path, KEYS, REQS)
        for row in batch:
            w.add(row)
        w.close()
    rows = [r for b in batches for r in b]
    text = path.read_text()
    assert text.splitlines()[0] == ",".join(columns(KEYS, REQS))
    assert text.count("link.loss,delay_s,seed") == 1
    back = read_rows(path, KEYS)
    assert len(back) == len(rows)
    for r, b in zip(rows, back, strict=True):
        assert _same({k: r[k] for k in columns(KEYS, REQS)}, b), (r, b)


def test_a_table_that_does_not_exist_has_no_rows_and_rows_without_the_keys_are_not_read(tmp_path):
    assert read_rows(tmp_path / TABLE, KEYS) == []
    (tmp_path / TABLE).touch()  # an empty file (a campaign stopped before its header): one is written
    w = TableWriter(tmp_path / TABLE, ["other"], [])
    w.add({"other": 1.5, "seed": 3, "refined": 0, "passed": 1})
    w.close()
    assert read_rows(tmp_path / TABLE, KEYS) == []
    assert [r["other"] for r in read_rows(tmp_path / TABLE, ["other"])] == [1.5]


@settings(max_examples=60, deadline=None)
@given(rows=st.lists(_row(), max_size=8))
def test_the_sorted_table_is_the_same_rows_in_order_of_their_values_then_seeds(rows, tmp_path_factory):
    path = tmp_path_factory.mktemp("sorted") / TABLE
    path.write_text("an old table\n")
    write_sorted(path, KEYS, rows, REQS)
    back = read_rows(path, KEYS)
    assert [row_key(KEYS, b) for b in back] == sorted(row_key(KEYS, r) for r in rows)
    # the same rows: each read back is one written, counted with its duplicates
    remaining = [{k: r[k] for k in columns(KEYS, REQS)} for r in rows]
    for b in back:
        match = next(i for i, r in enumerate(remaining) if _same(r, b))
        remaining.pop(match)
    assert remaining == []
    assert [p.name for p in path.parent.iterdir()] == [TABLE]  # replaced whole, nothing left beside it


def test_a_rows_missing_cells_are_written_empty_and_read_back_as_missing(tmp_path):
    """A row without a metric or a requirement's robustness (a run that failed before it was
    judged): those cells empty, read back as NaN, the rest as written."""
    row = {
        "link.loss": 0.25,
        "delay_s": 0.0,
        "seed": 4,
        "refined": 0,
        "passed": 0,
        "failure": "crashed\r\nat 3 s\r",
    }
    write_sorted(tmp_path / TABLE, KEYS, [row], REQS)
    w = TableWriter(tmp_path / "appended.csv", KEYS, REQS)
    w.add(row)
    w.close()
    for name in (TABLE, "appended.csv"):
        (back,) = read_rows(tmp_path / name, KEYS)
        assert {k: back[k] for k in row} == row
        missing = set(columns(KEYS, REQS)) - set(row) - {"config"}
        assert missing and all(math.isnan(back[k]) for k in missing)
        assert back["config"] == ""


@settings(max_examples=200, deadline=None)
@given(st.floats(-1e3, 1e3), st.floats(-1e-6, 1e-6), st.integers(0, 9), st.integers(0, 9))
@example(0.5, 3e-13, 1, 1)  # the same to 12 decimals, not to 13
@example(0.5, 3e-12, 1, 1)
def test_two_runs_are_one_exactly_when_their_values_agree_to_12_decimals_and_their_seeds_agree(x, d, s1, s2):
    a = {"link.loss": x, "delay_s": 0.5, "seed": s1}
    b = {"link.loss": x + d, "delay_s": 0.5, "seed": s2}
    same = round(x, 12) == round(x + d, 12) and s1 == s2
    assert (row_key(KEYS, a) == row_key(KEYS, b)) == same
    # values from a CSV (text) identify a run as the numbers do
    assert row_key(KEYS, {k: str(v) for k, v in a.items()}) == row_key(KEYS, a)
