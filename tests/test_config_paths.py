"""Where a config's plug-in files are found (``config.load``): a file entry of the law, of the
vehicle model and of each link model in the fault plan is relative to the config that names it,
whichever config was loaded before with the same text; and a run's record names its plug-ins
without importing them, whichever way the same file was loaded before."""

import json
from pathlib import Path

import pytest
import yaml

from swarm_sitl.config.load import ConfigError, load_config, load_recorded
from tests.support import ROOT, USERS_LAW, USERS_VEHICLE, config_data, page_files, users_plugins

pytestmark = pytest.mark.unit

LAW, VEHICLE = USERS_LAW, USERS_VEHICLE
LINK = "my_link.py:DistanceDelay"
#: ``docs/links.md``'s files: its link model, and its plan naming it
_LINK_PAGE = page_files((ROOT / "docs" / "links.md").read_text())


def _with_plugins(folder: Path, text: str, name: str = "cfg.yaml") -> Path:
    """``folder`` holding a config of ``text`` and each plug-in file it names, as a user's own."""
    folder.mkdir(parents=True)
    users_plugins(folder)
    (folder / "my_link.py").write_text(_LINK_PAGE["my_link.py"])
    path = folder / name
    path.write_text(text)
    return path


def _text() -> str:
    data = config_data("paper")
    data["law"] = {"entry": LAW}
    data["vehicle"]["model"] = VEHICLE
    data["faults"] = yaml.safe_load(_LINK_PAGE["my_plan.yaml"])
    assert _entries(data)[2:] == [LINK]
    return yaml.safe_dump(data)


def _entries(data: dict) -> list[str]:
    """The law's, the vehicle model's and the fault plan's link models' entries of a config."""
    return [
        data["law"]["entry"],
        data["vehicle"]["model"],
        *(f["model"]["entry"] for f in data["faults"]["plan"]),
    ]


def test_a_configs_data_is_plain_json_and_yaml_and_reads_back_as_the_same_config(tmp_path):
    """What ``cfg.data()`` gives (a run directory's ``config.yaml``, a campaign's shipment) is
    made of JSON's types only (lists, not tuples), and reads back as the same data."""
    cfg = load_config(_with_plugins(tmp_path / "c", _text()))
    data = cfg.data()
    assert json.loads(json.dumps(data)) == data
    assert yaml.safe_load(yaml.safe_dump(data)) == data
    assert load_config(_with_plugins(tmp_path / "again", yaml.safe_dump(data))).data() == data


def test_each_file_entry_is_found_beside_the_config_that_names_it_whatever_was_loaded_before(tmp_path):
    """The same text in two folders, loaded one after the other and back (a config is kept from
    one load to the next while its file is unchanged): each time every entry names the file of
    the folder of the config loaded, absolutely."""
    text = _text()
    folders = [tmp_path / "a", tmp_path / "deeper" / "b"]
    paths = [_with_plugins(f, text) for f in folders]
    for path in [*paths, paths[0], paths[1]]:
        cfg = load_config(path)
        entries = _entries(cfg.data())
        assert len(entries) == 3
        for entry, named in zip(entries, (LAW, VEHICLE, LINK), strict=True):
            assert entry == f"{path.parent / named.split(':')[0]}:{named.split(':')[1]}", (path, entry)


def test_a_records_plugins_are_named_not_imported_whichever_way_the_file_was_loaded_before(tmp_path):
    """A run's record whose law file is gone (a moved run directory) reads as a record, and asked
    for its law class says it does not import it; the same file loaded to be flown is refused in
    one line naming the file, before or after."""
    path = _with_plugins(tmp_path / "run", _text(), "config.yaml")
    (tmp_path / "run" / "my_law.py").unlink()
    for _ in range(2):
        cfg = load_recorded(tmp_path / "run")  # (``load_recorded`` reads RUN_DIR/config.yaml)
        assert _entries(cfg.data())[0] == f"{tmp_path / 'run' / 'my_law.py'}:ConsensusPD"
        with pytest.raises(
            RuntimeError, match=r"^a config read from a run directory does not import its law$"
        ):
            cfg.law_class()
        with pytest.raises(ConfigError, match=r"my_law\.py") as e:
            load_config(path)
        assert "\n" not in str(e.value)


def test_a_fault_plan_file_finds_its_link_model_beside_itself_not_beside_the_config(tmp_path):
    """``--faults PLAN`` (``with_faults``): a link model named by a file relative to the plan is
    the file beside the plan, wherever the config was read from."""
    from swarm_sitl.config.load import with_faults

    cfg = load_config(_with_plugins(tmp_path / "configs", _text()))
    plans = tmp_path / "plans" / "deeper"
    plans.mkdir(parents=True)
    (plans / "my_link.py").write_text(_LINK_PAGE["my_link.py"])
    (plans / "plan.yaml").write_text(_LINK_PAGE["my_plan.yaml"])
    flown = with_faults(cfg, plans / "plan.yaml")
    assert [f["model"]["entry"] for f in flown.data()["faults"]["plan"]] == [
        f"{plans / 'my_link.py'}:DistanceDelay"
    ]


@pytest.mark.parametrize("where", ["law", "vehicle model", "link model"])
def test_an_entry_that_cannot_name_a_plugin_is_one_whole_line_naming_the_key_that_holds_it(tmp_path, where):
    """A file entry whose name is no Python name, as the law, the vehicle model or a fault plan's
    link model: refused before anything is imported, naming the file and the key."""
    data = config_data("paper")
    bad = "my_law.py:1st"
    key = {"law": "law", "vehicle model": "vehicle.model", "link model": "faults"}[where]
    if where == "law":
        data["law"] = {"entry": bad}
    elif where == "vehicle model":
        data["vehicle"]["model"] = bad
    else:
        data["faults"] = {"plan": [{"all_edges": True, "model": {"entry": bad}}]}
    path = tmp_path / "cfg.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError) as e:
        load_config(path)
    assert str(e.value) == (
        f"{path}: {key}: entry {bad!r} must be 'package.module:ClassName' or 'path/file.py:ClassName'"
    )
