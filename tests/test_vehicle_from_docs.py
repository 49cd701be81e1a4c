"""A vehicle model written from ``docs/vehicles.md`` alone, outside the repository: the page's
file, in a temporary directory, through the page's commands (new --vehicle, check, sim, run),
with no edit of the package; the run as processes equals ``sim`` bit for bit. And the ways such
a model is refused: an entry that does not exist, or a class that does not meet the contract."""

import re

import numpy as np
import pytest

from sim_vehicles.models.build import build_vehicle
from sim_vehicles.models.vehicle_config import VehicleConfig, VehicleConfigError
from tests.support import ROOT, page_command, page_files

#: its system tests run in lockstep or ``sim`` only (no wall clock): free to run beside others
pytestmark = pytest.mark.lockstep

GUIDE = ROOT / "docs" / "vehicles.md"
COMMANDS = [
    "swarm-sitl new --followers 4 --graph layered --duration 12 --vehicle my_vehicle.py:LaggyVtol"
    " -o my_swarm.yaml",
    "swarm-sitl check my_swarm.yaml",
    "swarm-sitl sim my_swarm.yaml --out runs/mine-sim",
    "swarm-sitl run my_swarm.yaml --out runs/mine-run",
]


@pytest.mark.system
def test_the_guides_vehicle_loads_by_its_entry_and_flies_as_processes_equal_to_sim(tmp_path):
    text = GUIDE.read_text()
    files = page_files(text)
    assert set(files) == {"my_vehicle.py"}
    (tmp_path / "my_vehicle.py").write_text(files["my_vehicle.py"])
    for cmd in COMMANDS:
        assert cmd in text  # the page says exactly these
        r = page_command(cmd, tmp_path)
        assert r.returncode == 0, f"{cmd}: {r.stdout}{r.stderr}"
    sim, run = tmp_path / "runs" / "mine-sim", tmp_path / "runs" / "mine-run"
    assert '"model": "' in (run / "procs" / "vehicle_1.config.json").read_text()
    for i in range(1, 5):
        a, b = np.load(sim / f"follower_{i}.npz"), np.load(run / f"follower_{i}.npz")
        for key in a.files:
            assert np.array_equal(a[key], b[key], equal_nan=True), (i, key)
        err = np.linalg.norm(a["pos_err_m"], axis=1)
        assert err[a["t_s"] >= 9].max() < 0.05  # in formation with its lagging thrust


@pytest.mark.unit
def test_a_model_entry_that_does_not_exist_or_does_not_meet_the_contract_is_one_line(tmp_path):
    bad = tmp_path / "bad_vehicle.py"
    bad.write_text(
        "class NoAdvance:\n    def __init__(self, spec, state0, dt_s):\n        self.state = state0\n"
    )
    cases = [
        (f"{tmp_path / 'none.py'}:X", "no such file"),
        (f"{bad}:Missing", "has no 'Missing'"),
        (f"{bad}:NoAdvance", "does not meet the vehicle contract: no params, dt_s, step_index"),
        ("quad9", "is not one of paper_vtol, px4_quad_x nor an entry"),
    ]
    for model, named in cases:
        with pytest.raises(VehicleConfigError, match=re.escape(named)) as e:
            build_vehicle(VehicleConfig(model=model), 1)
        assert "\n" not in str(e.value)
    raising = tmp_path / "raising_vehicle.py"
    raising.write_text(
        "class Boom:\n    def __init__(self, spec, state0, dt_s):\n        raise RuntimeError('no')\n"
    )
    with pytest.raises(VehicleConfigError, match="building it raised RuntimeError: no"):
        build_vehicle(VehicleConfig(model=f"{raising}:Boom"), 1)


@pytest.mark.unit
def test_the_template_is_a_model_that_meets_the_contract_and_flies_a_lagging_thrust():
    """``models/template.py``'s ``LaggyVtol``: a hover command from rest at a thrust of zero
    reaches the weight as ``1 - exp(-t / tau)``: after one time constant, 63 % of it."""
    spec = VehicleConfig(model="sim_vehicles.models.template:LaggyVtol", params={"THRUST_TAU_S": 0.05})
    v = build_vehicle(spec, 1)
    v.thrust_N = 0.0  # type: ignore[attr-defined]
    v.advance(50)  # 50 ms: one time constant
    assert v.thrust_N == pytest.approx(v.params.hover_thrust_N * (1 - np.exp(-1)), rel=1e-9)  # type: ignore[attr-defined]
    assert (
        v.time_s == pytest.approx(0.05)
        and v.set_param("THRUST_TAU_S", 0.1)
        and not v.set_param("THRUST_TAU_S", 2)
    )
