"""How a plug-in is named and what it declares (``sim_vehicles.common.entry``), the rules every
plug-in kind (a law, a vehicle model, a link model) shares: an entry ``where:Name`` split at its
last colon (a file's path may hold colons of its own), a file entry made absolute against the
config's folder, and the parameter names a ``Params`` declares, whatever kind of class it is."""

import dataclasses
from pathlib import Path
from typing import NamedTuple

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import BaseModel, Field

from sim_vehicles.common.entry import EntryError, absolute_entry, declared_params, is_file_entry, split_entry

pytestmark = pytest.mark.unit

#: a folder name, colons and dots included (a file's path may hold either)
_PART = st.text(alphabet="abc:.-_", min_size=1, max_size=6).filter(lambda s: s not in (".", ".."))
_NAME = st.from_regex(r"[A-Za-z_][A-Za-z0-9_]{0,8}", fullmatch=True)


@settings(max_examples=40)
@given(parts=st.lists(_PART, min_size=1, max_size=3), name=_NAME)
def test_a_file_entry_is_split_at_its_last_colon_and_made_absolute_against_the_configs_folder(parts, name):
    where = "/".join([*parts, "law.py"])
    entry = f"{where}:{name}"
    assert split_entry(entry) == (where, name) and is_file_entry(entry)
    base = Path("/configs/here")
    assert absolute_entry(entry, base) == f"{(base / where).resolve()}:{name}"
    assert absolute_entry(f"/abs/{where}:{name}", base) == f"/abs/{where}:{name}"  # (already absolute)
    assert (
        not is_file_entry(f"pkg.module:{name}")
        and absolute_entry(f"pkg.module:{name}", base) == f"pkg.module:{name}"
    )


@pytest.mark.parametrize("entry", ["law.py", "law.py:", ":Law", "law.py:1st", "law.py:a.b"])
def test_an_entry_without_a_class_name_after_its_last_colon_is_one_line(entry):
    with pytest.raises(EntryError, match=r"must be 'package\.module:ClassName' or 'path/file\.py:ClassName'"):
        split_entry(entry)


class _Model(BaseModel):
    k: float = 1.0
    rate: float = Field(2.0, alias="rate_hz")


@dataclasses.dataclass
class _Data:
    k: float = 1.0
    rate: float = 2.0


class _Tuple(NamedTuple):
    k: float = 1.0
    rate: float = 2.0


class _Plain:
    def __init__(self, k: float = 1.0, *, rate: float = 2.0):
        self.k, self.rate = k, rate


class _Open:
    def __init__(self, k: float = 1.0, **more: float):
        self.k = k


@pytest.mark.parametrize(
    ("schema", "names"),
    [
        (_Model, {"k", "rate", "rate_hz"}),  # a pydantic model: its fields and their aliases
        (_Data, {"k", "rate"}),
        (_Tuple, {"k", "rate"}),
        (_Plain, {"k", "rate"}),  # any other class: its keyword parameters
        (_Open, None),  # ... and none where it takes any keyword
    ],
)
def test_the_names_a_params_class_declares_are_its_fields_or_keywords_whatever_its_kind(schema, names):
    assert declared_params(schema) == (None if names is None else frozenset(names))
