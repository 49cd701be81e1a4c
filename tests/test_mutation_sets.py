"""The mutation sets (``.ci/mutation``, ``pyproject.toml``'s ``[tool.mutmut]`` and
``[tool.swarm_sitl.mutation.*]``) leave no module out silently: every module of the tree is
mutated by exactly one set, or is named, itself or by its folder (for the modules of a folder
no set mutates), in ``[tool.swarm_sitl.mutation_outside]`` with why; every file a set names
exists, and so does every test file it runs."""

import tomllib

import pytest

from tests.support import ROOT

pytestmark = pytest.mark.unit


def _config() -> dict:
    with open(ROOT / "pyproject.toml", "rb") as f:
        return tomllib.load(f)


def test_every_module_is_in_one_mutation_set_or_outside_them_with_why():
    conf = _config()
    sets = {"laws": conf["tool"]["mutmut"]} | conf["tool"]["swarm_sitl"]["mutation"]
    outside = conf["tool"]["swarm_sitl"]["mutation_outside"]
    assert all(isinstance(why, str) and len(why) > 10 for why in outside.values())
    modules = sorted(
        p.relative_to(ROOT).as_posix()
        for package in ("swarm_sitl", "sim_vehicles")
        for p in (ROOT / package).rglob("*.py")
        if p.name != "__init__.py" and "mutants" not in p.parts
    )
    in_sets: dict[str, list[str]] = {}
    for name, s in sets.items():
        for m in s["only_mutate"]:
            assert (ROOT / m).is_file(), f"set {name} mutates {m}, which does not exist"
            in_sets.setdefault(m, []).append(name)
        for t in s["pytest_add_cli_args_test_selection"]:
            assert (ROOT / t).is_file(), f"set {name} runs {t}, which does not exist"
    for key in outside:
        assert (ROOT / key).exists(), f"mutation_outside names {key}, which does not exist"
    for m in modules:
        sets_of = in_sets.get(m, [])
        assert len(sets_of) <= 1, f"{m} is in more than one set: {sets_of}"
        if sets_of:  # (a folder outside may hold modules a set mutates; a module named may not)
            assert m not in outside, f"{m} is in set {sets_of[0]} and named outside the sets"
        else:
            assert any(m == key or m.startswith(key + "/") for key in outside), f"{m}: in no set, not named"
