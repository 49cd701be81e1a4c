"""Build the nodes of a swarm from a config: used by ``sim`` and by the per-process entry points."""

import numpy as np

from sim_vehicles.common.state import make_state
from sim_vehicles.mavlink.wire_format import f32
from sim_vehicles.plant.autopilot import Autopilot
from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.laws.follower import FollowerController, LeaderNode


def build_leader(cfg: SwarmConfig) -> LeaderNode:
    return LeaderNode(cfg.trajectory(), cfg.control_dt_s)


def build_controller(
    cfg: SwarmConfig,
    i: int,
    mass_kg: float | None = None,
    max_thrust_N: float | None = None,
    tick_phase_s: float = 0.0,
) -> FollowerController:
    """Follower ``i``'s controller. ``mass_kg``/``max_thrust_N`` default to the config's vehicle
    (a controller talking to a real autopilot passes what it read from the vehicle's parameters);
    ``tick_phase_s``: ``cfg.tick_phase_s`` in a real-time run."""
    f = cfg.follower(i)
    return FollowerController(
        i,
        f.offset_m,
        cfg.build_graph().in_neighbours(i),
        cfg.control_gains(mass_kg),
        cfg.control_dt_s,
        cfg.rates.estimator_substeps,
        cfg.hold,
        cfg.vehicle.max_thrust_N if max_thrust_N is None else max_thrust_N,
        tick_phase_s,
    )


def reported_vehicle_params(cfg: SwarmConfig) -> tuple[float, float]:
    """``(mass_kg, max_thrust_N)`` as a controller reads them over the MAVLink parameter protocol
    (float32): ``sim`` gives its controllers these, as a controller process gets them."""
    mass, max_thrust = f32(cfg.vehicle.mass_kg, cfg.vehicle.max_thrust_N)
    return mass, max_thrust


def build_autopilot(cfg: SwarmConfig, i: int) -> Autopilot:
    f = cfg.follower(i)
    x0 = make_state(f.initial_position_m, f.initial_velocity_mps, np.asarray(f.initial_quaternion_wxyz))
    return Autopilot(cfg.vehicle_params(), cfg.attitude_gains(), x0, cfg.attitude_dt_s)
