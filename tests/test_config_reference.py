"""``docs/config.md`` is what the schema gives, and the schema explains every key."""

from pathlib import Path

import pytest

from swarm_sitl.config.reference import reference

pytestmark = pytest.mark.unit
DOC = Path(__file__).resolve().parents[1] / "docs" / "config.md"


def test_the_config_reference_is_current():
    assert DOC.read_text() == reference(), (
        "docs/config.md is out of date: python -m swarm_sitl.config.reference > docs/config.md"
    )


def test_every_key_has_a_meaning():
    rows = [line for line in reference().splitlines() if line.startswith("| `")]
    assert len(rows) > 60  # every section's keys, the fault plan's included
    missing = [row.split("|")[1].strip() for row in rows if not row.rstrip("|").split("|")[-1].strip()]
    assert missing == [], f"keys without a #: comment in the schema: {missing}"
