"""A run's plug-ins packed and kept (``rundir.plugins``), for any config: which of its entries
are plug-ins, which get a copy, under which name, and what the config that flies again names.

Drawn: a law, a vehicle model and a plan whose entries are each a file (some of one stem with
other bytes, some missing), one of our modules, an installed package's module, or no entry at
all; data keys in any order. Held to the module's rules, stated here on their own:

- a file entry that exists is copied once per distinct content, as ``plugins/<stem>.py`` when
  its bytes are the first of that stem's, else ``plugins/<stem>_<sha256[:8]>.py``; the config
  names the copy, everything else in it is as it was;
- a module of another package is copied for the record, its entry kept; ours are hashed, not
  copied; a missing file is recorded with neither;
- ``keep`` writes exactly the copies and the manifest, and gives back the packed config in its
  own key order; kept twice, the same; where it cannot write, one line that names the place.
"""

import copy
import hashlib
import importlib.util
import json
import tempfile
from pathlib import Path
from types import SimpleNamespace
from typing import ClassVar

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm_sitl.rundir.plugins import MANIFEST, keep, manifest_of, pack, recorded_law
from swarm_sitl.rundir.whole_files import WriteError
from tests.strategies import EXAMPLES, FUZZ

pytestmark = pytest.mark.unit

OURS = ["swarm_sitl.faults.link_models:Bernoulli", "sim_vehicles.common.entry:EntryError"]
FOREIGN = ["json.decoder:JSONDecoder", "email.parser:Parser"]
STEMS = ["law", "link", "model"]
NOT_PLUGINS = ["no model", "model by name", "not a dict", "entry not str"]  #: plan items that name none
names = st.sampled_from(["MyLaw", "Model", "Link2"])


@st.composite
def plugin(draw):
    """``(kind, spec)``: a file ``(dir, stem, content)`` (missing: content None), ours, foreign."""
    kind = draw(st.sampled_from(["file", "file", "missing", "ours", "foreign"]))
    if kind in ("file", "missing"):
        content = None if kind == "missing" else draw(st.sampled_from([b"A = 1\n", b"B = 2\n", b"C = 3\n"]))
        return "file", (draw(st.integers(0, 2)), draw(st.sampled_from(STEMS)), content, draw(names))
    return kind, draw(st.sampled_from(OURS if kind == "ours" else FOREIGN))


@st.composite
def configs(draw):
    """A config's plug-in parts as ``{what: (kind, spec)}`` and the non-entries of its plan."""
    parts = {"law": draw(plugin())} if draw(st.booleans()) else {}
    vehicle = draw(st.one_of(st.none(), st.just("px4_quad_x"), plugin()))
    plan = draw(
        st.lists(
            st.one_of(plugin(), st.sampled_from(NOT_PLUGINS)),
            max_size=5,
        )
    )
    return parts, vehicle, plan, draw(st.permutations(["law", "vehicle", "faults", "seed"]))


def _entry(root: Path, kind: str, spec) -> str:
    if kind != "file":
        return spec
    d, stem, content, name = spec
    path = root / f"d{d}" / f"{stem}.py"
    if content is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        if not path.exists():  # one file per place: the first draw for it decides its bytes
            path.write_bytes(content)
    return f"{path}:{name}"


def _build(root: Path, drawn) -> tuple[dict, dict[str, str]]:
    """The config's data and ``{what: entry}`` of its plug-ins, in the order they are named."""
    parts, vehicle, plan_drawn, order = drawn
    plugins: dict[str, str] = {}
    data: dict = {}
    if "law" in parts:
        plugins["law"] = _entry(root, *parts["law"])
    if vehicle is None:
        vehicle_data: dict = {}
    elif vehicle == "px4_quad_x":
        vehicle_data = {"model": "px4_quad_x", "mass_kg": 1.5}
    else:
        plugins["vehicle"] = _entry(root, *vehicle)
        vehicle_data = {"model": plugins["vehicle"], "mass_kg": 1.5}
    plan: list = []
    for j, item in enumerate(plan_drawn):
        if item == "no model":
            plan.append({"at_s": 1.0})
        elif item == "model by name":
            plan.append({"model": "bernoulli"})
        elif item == "not a dict":
            plan.append("drop")
        elif item == "entry not str":
            plan.append({"model": {"entry": 3}})
        else:
            plugins[f"faults.plan.{j}"] = _entry(root, *item)
            plan.append({"at_s": 1.0, "model": {"entry": plugins[f"faults.plan.{j}"], "params": {"p": 0.1}}})
    parts_data = {
        "law": {"entry": plugins["law"], "params": {}} if "law" in plugins else {"params": {}},
        "vehicle": vehicle_data,
        "faults": {"plan": plan} if plan or vehicle is None else {},
        "seed": 7,
    }
    for key in order:
        if key != "faults" or plan or vehicle is not None:  # sometimes no faults section at all
            data[key] = parts_data[key]
    return data, plugins


def _file_of(entry: str) -> Path:
    where = entry.rpartition(":")[0]
    if where.endswith(".py"):
        return Path(where)
    spec = importlib.util.find_spec(where)
    assert spec is not None and spec.origin
    return Path(spec.origin)


def _expected_copies(plugins: dict[str, str]) -> dict[str, str | None]:
    """``what -> relative copy`` by the naming rule (the module docstring), in entry order."""
    first_of_stem: dict[str, bytes] = {}
    out: dict[str, str | None] = {}
    for what, entry in plugins.items():
        if entry in OURS or not _file_of(entry).is_file():
            out[what] = None
            continue
        src = _file_of(entry)
        body = src.read_bytes()
        first = first_of_stem.setdefault(src.stem, body)
        suffix = "" if body == first else f"_{hashlib.sha256(body).hexdigest()[:8]}"
        out[what] = f"plugins/{src.stem}{suffix}.py"
    return out


def _named(data: dict, what: str) -> object:
    if what == "law":
        return data["law"]["entry"]
    if what == "vehicle":
        return data["vehicle"]["model"]
    return data["faults"]["plan"][int(what.split(".")[-1])]["model"]["entry"]


@FUZZ
@given(drawn=configs())
def test_pack_copies_each_file_once_under_its_rule_and_names_the_copies(drawn):
    with tempfile.TemporaryDirectory() as tmp:
        data, plugins = _build(Path(tmp), drawn)
        before = copy.deepcopy(data)
        packed, files, manifest = pack(data)
        assert data == before  # the caller's data is not changed
        copies = _expected_copies(plugins)
        assert set(manifest) == set(plugins)
        assert set(files) == {c for c in copies.values() if c is not None}
        expected = copy.deepcopy(data)
        for what, entry in plugins.items():
            rel, src = copies[what], _file_of(entry)
            body = src.read_bytes() if src.is_file() else None
            sha = hashlib.sha256(body).hexdigest() if body is not None else None
            assert manifest[what] == {"entry": entry, "kept": rel, "sha256": sha}, what
            if rel is not None:
                assert files[rel] == body
            if rel is not None and entry.rpartition(":")[0].endswith(".py"):
                new = f"{rel}:{entry.rpartition(':')[2]}"
                if what == "law":
                    expected["law"]["entry"] = new
                elif what == "vehicle":
                    expected["vehicle"]["model"] = new
                else:
                    expected["faults"]["plan"][int(what.split(".")[-1])]["model"]["entry"] = new
        assert packed == expected
        assert list(packed) == list(data)  # in the config's own order
        for what in plugins:
            assert _named(packed, what) == _named(expected, what)


class _Law:
    message_length = 9
    record_fields: ClassVar[dict[str, int]] = {"u": 3, "x_hat": 6}


def _cfg(data: dict, recorded: bool = False) -> SimpleNamespace:
    return SimpleNamespace(
        is_recorded=recorded,
        data=lambda: copy.deepcopy(data),
        law_class=lambda: _Law,
        law=SimpleNamespace(entry=data["law"]["entry"]),
    )


@settings(FUZZ, max_examples=min(100, EXAMPLES))  # each writes a run directory twice
@given(drawn=configs().filter(lambda d: "law" in d[0]))
def test_keep_writes_the_copies_and_the_manifest_and_gives_the_packed_config(drawn):
    with tempfile.TemporaryDirectory() as tmp:
        data, _ = _build(Path(tmp) / "src", drawn)
        run_dir = Path(tmp) / "run"
        run_dir.mkdir()
        packed, files, manifest = pack(data)
        for _ in range(2):  # kept again into the same directory: the same, without an error
            text = keep(_cfg(data), run_dir)
            assert yaml.safe_load(text) == packed
            assert list(yaml.safe_load(text)) == list(packed)
            written = {str(p.relative_to(run_dir)): p.read_bytes() for p in run_dir.rglob("*.py")}
            assert written == files
            law = {**manifest["law"], "message_length": 9, "record_fields": {"u": 3, "x_hat": 6}}
            assert json.loads((run_dir / MANIFEST).read_text()) == {**manifest, "law": law}
            assert manifest_of(run_dir) == {**manifest, "law": law}
            assert recorded_law(run_dir) == law


def test_keep_of_a_recorded_config_gives_its_text_and_writes_nothing(tmp_path):
    (tmp_path / "config.yaml").write_text("seed: 3\n")
    data = {"law": {"entry": str(tmp_path / "gone.py") + ":Law"}}
    assert keep(_cfg(data, recorded=True), tmp_path) == "seed: 3\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["config.yaml"]


def test_keep_where_the_copies_cannot_go_names_the_place_in_one_line(tmp_path):
    law = tmp_path / "src" / "law.py"
    law.parent.mkdir()
    law.write_text("A = 1\n")
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "plugins").write_text("a file where the folder goes")
    with pytest.raises(WriteError) as e:
        keep(_cfg({"law": {"entry": f"{law}:Law"}}), run_dir)
    assert str(run_dir / "plugins") in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize(
    "text", ["", "[1, 2]", '{"law": 3}', '{"law": {"entry": "x"}}', '{"law": {"record_fields": 1}}']
)
def test_a_manifest_that_is_not_one_reads_as_none(tmp_path, text):
    (tmp_path / MANIFEST).write_text(text)
    assert recorded_law(tmp_path) is None
    assert manifest_of(tmp_path) == ({} if text in ("", "[1, 2]") else json.loads(text))
