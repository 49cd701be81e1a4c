"""A probe law for ``sim``'s tests (``tests/test_sim_ticks.py``, ``tests/test_sim_under_plans.py``):
it records everything it is handed (its context, each tick's time and sample, each in-neighbour's
message) and flies level on a thrust that changes every tick; and the paper's config flown by it.
"""

from pathlib import Path
from typing import Any

import numpy as np
import yaml

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.mavlink.wire_format import command_roundtrip
from swarm_sitl.config.load import load_config
from swarm_sitl.config.schema import SwarmConfig
from tests.support import config_data

SLOTS = 3  #: in-neighbours a probe records (the paper's graph: at most 2)

PROBE = f"""
import numpy as np
from swarm_sitl.laws.contract import AttitudeCommand, LawOutput

SLOTS = {SLOTS}


def thrust_fraction(k, i):
    '''The probe's thrust at tick k, as a fraction of its weight: a different one every tick.'''
    return 1.0 + 0.2 * np.sin(0.7 * k + i)


class Probe:
    message_length = 5  # its id, its tick's time, its sample's position
    record_fields = {{
        "ctx": 7, "weights": SLOTS, "outs": SLOTS, "first_draw": 1,
        "seen_t": 1, "sample_t": 1, "sample_p": 3, "sample_v": 3, "sample_q": 4,
        "from": SLOTS, "sent_at": SLOTS, "age": SLOTS, "said_id": SLOTS, "said_t": SLOTS, "ref_p": 3,
    }}

    def __init__(self, ctx):
        self.ctx = ctx
        weights = sum(w for _, w in ctx.in_edges)
        self.row = [ctx.follower_id, len(ctx.in_edges), weights, ctx.control_dt_s, ctx.mass_kg,
                    ctx.max_thrust_N, ctx.gravity_mps2]
        by_source = [w for _, w in sorted(ctx.in_edges)]
        self.weights = [*by_source, *[np.nan] * (SLOTS - len(by_source))]
        outs = sorted(ctx.out_neighbours)
        self.outs = [*outs, *[np.nan] * (SLOTS - len(outs))]
        self.first_draw = ctx.rng.random()

    def step(self, t_s, sample, inbox):
        ctx = self.ctx
        k = round(t_s / ctx.control_dt_s)
        thrust = ctx.mass_kg * ctx.gravity_mps2 * thrust_fraction(k, ctx.follower_id)
        command = AttitudeCommand(np.array([1.0, 0.0, 0.0, 0.0]), thrust)
        sources = sorted(inbox)
        pad = lambda xs: [*xs, *[np.nan] * (SLOTS - len(xs))]
        follower = lambda s, j: inbox[s].values[j] if s != 0 else np.nan
        record = {{
            "ctx": self.row,
            "weights": self.weights,
            "outs": self.outs,
            "first_draw": self.first_draw,
            "seen_t": t_s,
            "sample_t": sample.t_s,
            "sample_p": sample.p_W, "sample_v": sample.v_W, "sample_q": sample.q_WB,
            "from": pad(sources),
            "sent_at": pad([inbox[s].t_s for s in sources]),
            "age": pad([inbox[s].age_s for s in sources]),
            "said_id": pad([follower(s, 0) if s else 0.0 for s in sources]),
            "said_t": pad([follower(s, 1) for s in sources]),
            "ref_p": inbox[0].values[:3] if 0 in inbox else [np.nan] * 3,
        }}
        message = np.array([ctx.follower_id, t_s, *sample.p_W])
        return LawOutput(command, message, record)
"""


def probe_config(folder: Path, **changes: Any) -> dict:
    """The paper's config flown by the probe (its file written in ``folder``), with ``changes``
    (top-level keys) made."""
    (folder / "probe.py").write_text(PROBE)
    data = config_data("paper")
    data.update(law={"entry": "probe.py:Probe"}, **changes)
    return data


def loaded(folder: Path, data: dict) -> SwarmConfig:
    """``data`` written as ``folder/cfg.yaml`` and loaded as a run loads it."""
    (folder / "cfg.yaml").write_text(yaml.safe_dump(data))
    return load_config(folder / "cfg.yaml")


def climb_acceleration(cfg: SwarmConfig, thrust_N: float, full_thrust_N: float) -> float:
    """The vertical acceleration of a level vehicle holding a setpoint of ``thrust_N`` as the wire
    carries it (a fraction of the controller's ``full_thrust_N``, read back as one of the vehicle's
    maximum): ``T / m - g`` [m/s^2]."""
    level = AttitudeCommand(np.array([1.0, 0.0, 0.0, 0.0]), thrust_N)
    held = command_roundtrip(level, full_thrust_N, cfg.vehicle.max_thrust_N)
    return float(held.thrust_N) / cfg.vehicle.mass_kg - cfg.gravity_mps2
