"""The documentation's map: ``docs/README.md`` lists every page once, each link leads to a page,
and every path the README names exists."""

import re

import pytest

from tests.support import ROOT

pytestmark = pytest.mark.unit

DOCS = ROOT / "docs"


def test_the_index_lists_every_page_once_and_nothing_else():
    index = (DOCS / "README.md").read_text()
    linked = re.findall(r"\]\(([^)#]+\.md)\)", index)
    pages = sorted(str(p.relative_to(DOCS)) for p in DOCS.rglob("*.md") if p.name != "README.md")
    assert sorted(set(linked)) == pages, f"index links {sorted(set(linked))}, the pages are {pages}"
    assert len(linked) == len(set(linked)), f"a page listed twice: {linked}"


def test_every_path_the_readme_names_exists():
    """A path in backticks (``docs/laws.md``, ``configs/paper_quad.yaml``, ``examples/...``) is one
    a user can open: the README's map does not drift from the tree."""
    text = (ROOT / "README.md").read_text()
    paths = set(re.findall(r"`((?:docs|configs|examples|swarm_sitl|sim_vehicles|tests)/[\w./-]+)`", text))
    paths |= set(re.findall(r"\]\(((?:docs)/[\w./-]+)\)", text))
    assert paths, "the README names no path"
    missing = sorted(p for p in paths if not (ROOT / p).exists())
    assert not missing, f"the README names paths that do not exist: {missing}"
