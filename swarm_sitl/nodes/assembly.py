"""Build the nodes of a swarm from a config: used by ``sim`` and by the per-process entry points."""

import numpy as np

from sim_vehicles.mavlink.wire_format import f32
from sim_vehicles.models.build import build_vehicle
from sim_vehicles.plant.contract import VehicleModel
from swarm_sitl.bus.codec import Message
from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.laws.contract import LawContext, Received, VehicleSample, reference_values
from swarm_sitl.laws.trajectories import Trajectory
from swarm_sitl.nodes.law_host import HostedLaw, HostedStep, LawError, one_line


class Reference:
    """Node 0: the leader's message at each tick, its trajectory's exact p, v, a and jerk
    (``laws.contract.REFERENCE``)."""

    def __init__(self, trajectory: Trajectory, control_dt_s: float):
        self.trajectory = trajectory
        self.dt_s = control_dt_s

    def step(self, k: int) -> Message:
        t = k * self.dt_s
        values = reference_values(self.trajectory.derivatives(t))
        return Message(0, k, t, values, (float(values[0]), float(values[1]), float(values[2])))


def build_leader(cfg: SwarmConfig) -> Reference:
    return Reference(cfg.trajectory(), cfg.control_dt_s)


def law_context(
    cfg: SwarmConfig, i: int, mass_kg: float | None = None, max_thrust_N: float | None = None
) -> LawContext:
    """What follower ``i``'s law is built from. ``mass_kg``/``max_thrust_N`` default to the
    config's vehicle (a controller talking to a real autopilot passes what it read from the
    vehicle's parameters)."""
    graph = cfg.build_graph()
    return LawContext(
        follower_id=i,
        in_edges=tuple((int(s), float(w)) for s, w in graph.in_neighbours(i)),
        out_neighbours=tuple(int(d) for d in graph.out_neighbours(i)),
        control_dt_s=cfg.control_dt_s,
        mass_kg=cfg.vehicle.mass_kg if mass_kg is None else mass_kg,
        max_thrust_N=cfg.vehicle.max_thrust_N if max_thrust_N is None else max_thrust_N,
        gravity_mps2=cfg.gravity_mps2,
        offset_m=np.asarray(cfg.follower(i).offset_m, dtype=float),
        rng=np.random.default_rng([cfg.law.seed, i]),
        params=cfg.law_params(),
    )


def build_law(
    cfg: SwarmConfig, i: int, mass_kg: float | None = None, max_thrust_N: float | None = None
) -> HostedLaw:
    """Follower ``i``'s law (``law.entry``), built and hosted (``law_host``); ``LawError`` if
    building it raises."""
    ctx = law_context(cfg, i, mass_kg, max_thrust_N)
    try:
        law = cfg.law_class()(ctx)
    except Exception as e:
        raise LawError(f"law {cfg.law.entry}, follower {i}: building it raised {one_line(e)}") from e
    return HostedLaw(law, i, cfg.law.entry)


def first_tick(
    cfg: SwarmConfig, i: int, mass_kg: float | None = None, max_thrust_N: float | None = None
) -> HostedStep:
    """Build follower ``i``'s law and step it at t = 0 on its initial state, the leader's reference
    (if it hears node 0) and zeros from its other in-neighbours: what a run's first tick gives it
    (``LawError`` if it cannot)."""
    law = build_law(cfg, i, mass_kg, max_thrust_N)
    f = cfg.follower(i)
    ref = reference_values(cfg.trajectory().derivatives(0.0))
    inbox = {
        s: Received(ref if s == 0 else np.zeros(law.message_length), 0.0, 0.0)
        for s, _ in cfg.build_graph().in_neighbours(i)
    }
    sample = VehicleSample(
        0.0,
        np.asarray(f.initial_position_m, dtype=float),
        np.asarray(f.initial_velocity_mps, dtype=float),
        np.asarray(f.initial_quaternion_wxyz, dtype=float),
    )
    return law.step(0.0, sample, inbox)


def reported_vehicle_params(cfg: SwarmConfig) -> tuple[float, float]:
    """``(mass_kg, max_thrust_N)`` as a controller reads them over the MAVLink parameter protocol
    (float32): ``sim`` gives its laws these, as a controller process gets them."""
    mass, max_thrust = f32(cfg.vehicle.mass_kg, cfg.vehicle.max_thrust_N)
    return mass, max_thrust


def build_autopilot(cfg: SwarmConfig, i: int) -> VehicleModel:
    """Follower ``i``'s vehicle, built as its process builds it: from its spec."""
    return build_vehicle(cfg.vehicle_spec(i), i)
