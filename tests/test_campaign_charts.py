"""A campaign's figures (``campaigns.charts``) show what the table holds, for any table: the error
chart a dot per run at its value, the median over the seeds through them, the band from the least
to the largest, the bound, and the breaking point where the table has one; the heat map each
cell's median over the seeds, an x on every cell where a seed failed, its colour scale from the
least to the largest positive median. Each figure is read back from matplotlib's own objects
(``plt.close`` held off while the test reads it), against the rows computed here."""

import math
from pathlib import Path

import matplotlib
import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from swarm_sitl.campaigns import charts
from swarm_sitl.campaigns.breaking import breaking_point

matplotlib.use("Agg")
import matplotlib.pyplot as plt

pytestmark = pytest.mark.unit

KEY, KEY2 = "link.loss", "link.delay_s"
_err = st.one_of(st.floats(1e-6, 10.0), st.just(math.nan), st.just(0.0))  # (0: none, off a log scale)
_rows = st.lists(
    st.tuples(st.sampled_from([0.0, 0.1, 0.25, 0.5]), st.sampled_from([0.0, 0.2]), _err, st.booleans()),
    min_size=1,
    max_size=12,
).map(lambda rs: [{KEY: v, KEY2: w, "max_error_m": e, "passed": int(ok)} for v, w, e, ok in rs])


@pytest.fixture
def kept(monkeypatch):
    """The figures drawn, kept open (their ``close`` held off) and closed after the test; not
    rendered to a file (``savefig`` held off: the last test writes them)."""
    close = plt.close

    def last():
        *older, newest = plt.get_fignums()
        for n in older:  # (hypothesis draws many in one test: the earlier ones are read)
            close(n)
        return plt.figure(newest)

    monkeypatch.setattr(plt, "close", lambda *a, **k: None)
    monkeypatch.setattr(
        matplotlib.figure.Figure, "savefig", lambda self, path, **k: Path(path).write_bytes(b"kept")
    )
    yield last
    monkeypatch.undo()
    plt.close("all")


def _per_value(rows: list[dict], key: str) -> tuple[list[float], list[list[float]]]:
    values = sorted({float(r[key]) for r in rows})
    return values, [[float(r["max_error_m"]) for r in rows if float(r[key]) == v] for v in values]


def _same(a, b) -> bool:
    return np.array_equal(np.asarray(a, float), np.asarray(b, float), equal_nan=True)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(rows=_rows, bound=st.floats(1e-4, 1.0))
@example(rows=[{KEY: 0.0, KEY2: 0.0, "max_error_m": 1.0, "passed": 0}] * 2, bound=1.0)
def test_the_error_chart_shows_each_run_the_median_the_band_the_bound_and_the_breaking_point(
    tmp_path, kept, rows, bound
):
    path = charts.error_chart(rows, KEY, bound, tmp_path / "e.png", "the title")
    assert path == tmp_path / "e.png" and path.read_bytes() == b"kept"
    ax = kept().axes[0]
    assert ax.get_yscale() == "log" and ax.get_xlabel() == KEY and ax.get_title() == "the title"
    assert ax.get_ylabel() == "largest formation error after settling [m]"
    values, per = _per_value(rows, KEY)
    medians = [np.nanmedian(p) if np.isfinite(p).any() else math.nan for p in per]
    lines = {(ln.get_marker(), ln.get_linestyle()): ln for ln in ax.lines}
    median = lines[("o", "-")]
    assert _same(median.get_xdata(), values) and _same(median.get_ydata(), medians)
    dots = [ln for ln in ax.lines if ln.get_marker() == "."]
    assert len(dots) == len(values)
    for d, v, p in zip(dots, values, per, strict=True):
        assert list(d.get_xdata()) == [v] * len(p) and _same(d.get_ydata(), p)
    flat = [e for p in per for e in p if math.isfinite(e)]
    band = np.concatenate([p.vertices for p in ax.collections[0].get_paths()]) if flat else np.empty((0, 2))
    if flat:
        assert band[:, 1].min() == pytest.approx(min(flat)) and band[:, 1].max() == pytest.approx(max(flat))
    level = [ln for ln in ax.lines if ln.get_linestyle() == "--"]
    assert len(level) == 1 and level[0].get_label() == f"bound {bound:g} m"
    assert list(level[0].get_ydata()) == [bound, bound] and list(level[0].get_xdata()) == [0, 1]  # (across)
    held, broke = breaking_point(rows, KEY)
    upright = [ln for ln in ax.lines if ln.get_linestyle() == ":"]
    if held is not None and broke is not None:
        assert len(upright) == 1 and list(upright[0].get_xdata()) == [held, held]
        assert upright[0].get_label() == f"holds up to {held:g}"
    else:
        assert not upright
    named = {"min to max over seeds", "median", f"bound {bound:g} m"} | {ln.get_label() for ln in upright}
    assert {t.get_text() for t in ax.get_legend().get_texts()} == named  # (what each mark is)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(rows=_rows, bound=st.floats(1e-4, 1.0))
@example(rows=[{KEY: 0.0, KEY2: 0.0, "max_error_m": 1.0, "passed": 0}] * 2, bound=1.0)
def test_the_heat_map_shows_each_cells_median_and_marks_every_cell_where_a_seed_failed(
    tmp_path, kept, rows, bound
):
    assert charts.heat_map(rows, [KEY, KEY2], bound, tmp_path / "h.png", "the title") == tmp_path / "h.png"
    assert (tmp_path / "h.png").read_bytes() == b"kept"
    fig = kept()
    ax = fig.axes[0]
    xs, ys = sorted({r[KEY] for r in rows}), sorted({r[KEY2] for r in rows})
    z = np.full((len(ys), len(xs)), np.nan)
    failed = set()
    for j, y in enumerate(ys):
        for i, x in enumerate(xs):
            cell = [r for r in rows if r[KEY] == x and r[KEY2] == y]
            errs = [r["max_error_m"] for r in cell]
            if np.isfinite(errs).any():
                z[j, i] = np.nanmedian(errs)
            if any(not r["passed"] for r in cell):
                failed.add((i, j))
    image = ax.images[0]
    assert _same(np.ma.filled(image.get_array(), np.nan), z)
    assert {(t.get_position(), t.get_text()) for t in ax.texts} == {((i, j), "x") for i, j in failed}
    assert [t.get_text() for t in ax.get_xticklabels()] == [f"{x:g}" for x in xs]
    assert [t.get_text() for t in ax.get_yticklabels()] == [f"{y:g}" for y in ys]
    assert (ax.get_xlabel(), ax.get_ylabel()) == (KEY, KEY2)
    assert ax.get_title() == f"the title (x: a seed past {bound:g} m)"
    positive = z[np.isfinite(z) & (z > 0)]
    if positive.size:  # (one value: matplotlib widens the scale around it)
        assert isinstance(image.norm, matplotlib.colors.LogNorm)
        assert image.norm.vmin <= positive.min() <= positive.max() <= image.norm.vmax
        if positive.min() < positive.max():
            assert (image.norm.vmin, image.norm.vmax) == (positive.min(), positive.max())
    assert len(fig.axes) == 2  # (the colour bar)
    assert fig.axes[1].get_ylabel() == "median largest error after settling [m]"
    bottom, top = ax.get_ylim()
    assert bottom < top  # (the first value of KEY2 at the bottom, as on any axis)


def test_the_figures_are_written_where_asked(tmp_path):
    rows = [{KEY: 0.0, KEY2: 0.0, "max_error_m": 0.01, "passed": 1}]
    for draw, name in ((charts.error_chart, "a.png"), (charts.heat_map, "b.png")):
        keys = KEY if draw is charts.error_chart else [KEY, KEY2]
        out = draw(rows, keys, 0.1, tmp_path / name, "t")
        assert out == tmp_path / name and Path(out).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not plt.get_fignums()  # (each closed once written)
