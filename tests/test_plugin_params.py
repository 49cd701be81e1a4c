"""A plug-in's parameters are the ones it declares, for every kind (law, vehicle model, link
model), whatever the plug-in's own code would let through: any other name is one line naming
it, from the config's load and from ``check``, ``sim`` and ``run`` (exit 2); a number is a
number (``true`` is not 1.0). And ``check`` holds a link model's ``fates`` to its ``fate``."""

import re
import subprocess

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm_sitl.config.load import ConfigError, parse_config
from swarm_sitl.faults.link_model import fates_disagreement
from swarm_sitl.faults.plan import FaultEntry
from tests.support import CONFIGS, ROOT, cli, page_files, start_cli

#: plug-ins of each kind, in one file: each declares ``k`` and ``tau_s`` (a pydantic ``Params``
#: that lets extra keys through, a dataclass, a vehicle's ``tunables``)
PLUGINS = '''
import dataclasses

import numpy as np
from pydantic import BaseModel, ConfigDict

from swarm_sitl.faults.link_model import Effect, Effects
from swarm_sitl.laws.template import HoverLaw
from sim_vehicles.models.template import LaggyVtol


class Loose(BaseModel):
    model_config = ConfigDict(extra="allow")  # (its own code would take anything)
    k: float = 1.0
    tau_s: float = 0.1


class LooseLaw(HoverLaw):
    Params = Loose


@dataclasses.dataclass
class Fixed:
    k: float = 1.0
    tau_s: float = 0.1


class DataclassLaw(HoverLaw):
    Params = Fixed


class NoParamsLaw(HoverLaw):
    Params = None


class LooseLink:
    Params = Loose

    def fate(self, p, m):
        return None


class TunedVehicle(LaggyVtol):
    """Its parameters: its tunables (THRUST_TAU_S), a name it ignores (k) not among them."""


class DeclaredVehicle(LaggyVtol):
    Params = Fixed

    def __init__(self, spec, state0, dt_s):
        super().__init__(dataclasses.replace(spec, params={}), state0, dt_s)


class LyingLink:
    """fates() drops a message fate() delivers, one step in 97."""

    Params = Loose

    def fate(self, p, m):
        return Effect(lost=True) if m.uniform(1) < 0.5 else None

    def fates(self, p, ms):
        lost = ms.uniform(1) < 0.5
        lost = lost | (ms.steps % 97 == 13)
        none = np.zeros(len(ms.steps), bool)
        return Effects(lost, none, np.zeros(len(ms.steps)), none)
'''


@pytest.fixture(scope="module")
def plugins(tmp_path_factory):
    path = tmp_path_factory.mktemp("plugins") / "plugins.py"
    path.write_text(PLUGINS)
    return path


def _data(plugins, kind: str, cls: str, params: dict) -> dict:
    data = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    if kind == "law":
        data["law"] = {"entry": f"{plugins}:{cls}", "params": params}
    elif kind == "vehicle":
        data["vehicle"] = {**data["vehicle"], "model": f"{plugins}:{cls}", "params": params}
    else:
        data["faults"] = {
            "plan": [{"all_edges": True, "model": {"entry": f"{plugins}:{cls}", "params": params}}]
        }
    return data


CASES = [  # kind, plug-in, what it declares
    ("law", "LooseLaw", {"k", "tau_s"}),
    ("law", "DataclassLaw", {"k", "tau_s"}),
    ("law", "NoParamsLaw", set()),
    ("link", "LooseLink", {"k", "tau_s"}),
    ("vehicle", "TunedVehicle", {"THRUST_TAU_S"}),
    ("vehicle", "DeclaredVehicle", {"k", "tau_s"}),
]
names = st.from_regex(r"[A-Za-z_][A-Za-z0-9_]{0,12}", fullmatch=True)


@pytest.mark.unit
@settings(max_examples=12, deadline=None)
@given(
    case=st.sampled_from(CASES), extra=st.lists(names, min_size=0, max_size=3, unique=True), data=st.data()
)
def test_a_name_a_plugin_does_not_declare_is_one_line_naming_it_for_every_kind(plugins, case, extra, data):
    kind, cls, declared = case
    given_names = data.draw(st.sets(st.sampled_from(sorted(declared))) if declared else st.just(set()))
    params = {n: 0.05 for n in given_names} | {n: 0.05 for n in extra if n not in declared}
    unknown = sorted(n for n in extra if n not in declared)
    if not unknown:
        parse_config(_data(plugins, kind, cls, params))  # every name declared: it loads
        return
    with pytest.raises(ConfigError) as e:
        parse_config(_data(plugins, kind, cls, params))
    line = str(e.value)
    assert "\n" not in line and f"has no parameter {', '.join(unknown)}" in line, line
    assert (f"it has {', '.join(sorted(declared))}" if declared else "it declares none") in line


@pytest.mark.unit
@pytest.mark.parametrize("value", [True, False, "0.3", None, float("inf"), [0.3]])
def test_a_vehicle_parameter_is_a_finite_number_not_a_bool_or_text(value):
    data = yaml.safe_load((CONFIGS / "paper_quad.yaml").read_text())
    data["vehicle"]["params"] = {"T_TAU_S": value}
    with pytest.raises(ConfigError, match=r"vehicle[.:] ?params[.:] ?T_TAU_S") as e:
        parse_config(data)
    assert "\n" not in str(e.value)


def _spawn(args: list[str], cwd) -> subprocess.Popen:
    return start_cli(*args, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=False)


@pytest.mark.system
@pytest.mark.lockstep  # (refused before anything flies)
def test_a_misspelled_parameter_is_one_line_exit_2_from_check_sim_and_run(tmp_path):
    """The two cases of issue 46 as a user met them: a link model's ``duty: 0.3`` and the guide's
    vehicle's ``THRUST_TAU: 0.3``, each refused by ``check``, ``sim`` and ``run`` before anything
    flies, in one line naming the parameter and the ones the plug-in has."""
    (tmp_path / "my_vehicle.py").write_text(
        page_files((ROOT / "docs" / "vehicles.md").read_text())["my_vehicle.py"]
    )
    (tmp_path / "duty_link.py").write_text(
        "from pydantic import BaseModel, Field\n\n"
        "class DutyCycleOutage:\n"
        "    class Params(BaseModel):\n"
        "        period_s: float = Field(gt=0)\n"
        "        on_fraction: float = Field(ge=0, le=1)\n\n"
        "    def fate(self, p, m):\n"
        "        return None\n"
    )
    data = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    link = {
        **data,
        "faults": {
            "plan": [
                {
                    "all_edges": True,
                    "model": {
                        "entry": "duty_link.py:DutyCycleOutage",
                        "params": {"period_s": 1.0, "on_fraction": 0.5, "duty": 0.3},
                    },
                }
            ]
        },
    }
    vehicle = {
        **data,
        "vehicle": {**data["vehicle"], "model": "my_vehicle.py:LaggyVtol", "params": {"THRUST_TAU": 0.3}},
    }
    (tmp_path / "link.yaml").write_text(yaml.safe_dump(link))
    (tmp_path / "vehicle.yaml").write_text(yaml.safe_dump(vehicle))
    wants = {
        "link.yaml": "has no parameter duty (it has on_fraction, period_s)",
        "vehicle.yaml": "has no parameter THRUST_TAU (it has THRUST_TAU_S)",
    }
    procs = {
        (cfg, cmd): _spawn(
            [cmd, cfg, *(["--out", str(tmp_path / f"out-{cmd}")] if cmd != "check" else [])], tmp_path
        )
        for cfg in wants
        for cmd in ("check", "sim", "run")
    }
    for (cfg, cmd), p in procs.items():
        out, err = p.communicate(timeout=120)
        lines = err.strip().splitlines()
        assert p.returncode == 2 and len(lines) == 1 and wants[cfg] in lines[0], (cfg, cmd, out, err)
        assert not (tmp_path / f"out-{cmd}").exists()


@pytest.mark.unit
@settings(max_examples=20, deadline=None)
@given(
    key=st.sampled_from(["loss", "duplicate", "corrupt", "reorder", "delay_s", "bursty", "bandwidth"]),
    p=st.floats(0.01, 1.0),
    seed=st.integers(0, 2**32),
)
def test_every_built_in_model_with_fates_agrees_with_its_fate_as_check_draws_them(key, p, seed):
    """The check ``swarm-sitl check`` runs on a user's model, run on every built-in one with
    ``fates`` (random parameters, plan seeds, links and steps): none disagrees."""
    how = {
        "bursty": {"bursty": {"p": p, "r": max(p, 0.05), "loss_bad": 0.9, "loss_good": 0.01}},
        "bandwidth": {"bandwidth": {"rate_bps": 2000 + 1e5 * p}},
        "delay_s": {"delay_s": p / 5, "jitter_s": p / 10},
    }.get(key, {key: p})
    what = {"out_of": 1} if key == "bandwidth" else {"edge": [1, 2]}  # (a radio: its sender)
    model, params = FaultEntry.model_validate({**what, **how}).link_how
    assert fates_disagreement(model, params, 0.01, seed) is None


@pytest.mark.unit
def test_check_names_the_first_message_a_models_fates_and_fate_disagree_on(plugins, tmp_path):
    from swarm_sitl.commands.tools import link_model_lines

    cfg = parse_config(_data(plugins, "link", "LyingLink", {}))
    lines = link_model_lines(cfg)
    assert len(lines) == 1 and "LyingLink" in lines[0]
    step = int(re.search(r"at step (\d+)", lines[0]).group(1))
    assert step % 97 == 13 and "fate() says" in lines[0] and "fates() lost" in lines[0], lines
    honest = parse_config(_data(plugins, "link", "LooseLink", {}))
    assert link_model_lines(honest) == []  # (no fates: nothing to hold it to)
    r = cli("check", str(_write(tmp_path, _data(plugins, "link", "LyingLink", {}))), timeout=120)
    assert r.returncode == 1 and "disagree at step" in r.stdout, (r.stdout, r.stderr)


def _write(tmp_path, data: dict):
    path = tmp_path / "lying.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.system
@pytest.mark.lockstep  # (nothing flies)
def test_new_writes_a_config_for_a_model_with_a_required_parameter_given_on_the_command_line(tmp_path):
    """``new --vehicle`` for a model whose ``Params`` has a required field: without it, one line
    naming it and the flag that gives it; with ``--vehicle-param``, a config whose
    ``vehicle.params`` holds it, which loads."""
    (tmp_path / "req_vehicle.py").write_text(
        "from pydantic import BaseModel, Field\n"
        "from sim_vehicles.models.template import LaggyVtol\n\n"
        "class Req(BaseModel):\n"
        "    THRUST_TAU_S: float = Field(ge=0, le=1)\n\n"
        "class ReqVtol(LaggyVtol):\n"
        "    Params = Req\n"
    )
    base = [
        "new",
        "--followers",
        "3",
        "--vehicle",
        "req_vehicle.py:ReqVtol",
    ]
    r = cli(*base, "-o", "a.yaml", cwd=tmp_path, timeout=120)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and "THRUST_TAU_S: Field required" in lines[0], r.stderr
    assert "--vehicle-param NAME=VALUE" in lines[0] and not (tmp_path / "a.yaml").exists()
    r = cli(*base, "--vehicle-param", "THRUST_TAU_S=0.02", "-o", "a.yaml", cwd=tmp_path, timeout=120)
    assert r.returncode == 0, r.stderr
    from swarm_sitl.config.load import load_config

    assert load_config(tmp_path / "a.yaml").vehicle.params == {"THRUST_TAU_S": 0.02}
