"""A requirement's signals are declared once (``specs.requirement``: name, unit, meaning), and what
computes them (``rundir.requirements``) and the guide's table (``docs/specs.md``) hold to that
declaration: a signal added, renamed or dropped in one place and not the others fails here."""

import re

import pytest

from swarm_sitl.rundir.requirements import edge_signals, follower_signals
from swarm_sitl.running.sim import run_sim
from swarm_sitl.specs.requirement import EDGE_SIGNALS, FOLLOWER_SIGNALS, PAIR_SIGNALS, Edge
from tests.support import ROOT, config


def _table_row(over: str) -> set[str]:
    """The signal names (in backticks, their explanations in brackets left out) of the row of
    ``docs/specs.md``'s table for ``over``."""
    text = (ROOT / "docs" / "specs.md").read_text()
    row = next(line for line in text.splitlines() if line.startswith(f"| `{over}` |"))
    signals = re.sub(r"\([^)]*\)", "", row.rstrip(" |").rsplit(" | ", 1)[1])  # (what each is)
    return set(re.findall(r"`([a-z_]+)`", signals))


@pytest.mark.unit
@pytest.mark.parametrize(
    ("over", "declared"), [("followers", FOLLOWER_SIGNALS), ("pairs", PAIR_SIGNALS), ("edges", EDGE_SIGNALS)]
)
def test_the_guides_table_names_exactly_the_declared_signals(over, declared):
    assert _table_row(over) == set(declared)


@pytest.mark.integration
def test_what_a_run_computes_is_exactly_the_declared_signals_each_per_tick():
    """A short ``sim`` of the paper's swarm (its law records ``p_hat``, so every follower signal
    is there): each follower's and each edge's signals are the declared names, one value per tick."""
    cfg = config("paper").model_copy(update={"duration_s": 0.2})
    rec = run_sim(cfg)
    for i in rec.followers:
        got = follower_signals(rec, cfg, i, [])
        assert set(got) == set(FOLLOWER_SIGNALS), i
        assert all(len(v) == len(rec.followers[i]["t_s"]) for v in got.values())
    for src, dst in cfg.graph_edges():
        got = edge_signals(rec, cfg, Edge(src, dst))
        assert set(got) == set(EDGE_SIGNALS), (src, dst)
