"""Build the nodes of a swarm from a config: used by ``sim`` and by the per-process entry points."""

import numpy as np

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.mavlink.ardupilot_guided import guided_command
from sim_vehicles.mavlink.ardupilot_profile import THRUST_AS_THRUST, ArduCopterState
from sim_vehicles.mavlink.thrust_map import boost_compensated, full_thrust_N, hover_fraction
from sim_vehicles.mavlink.wire_format import command_roundtrip, encode_attitude_target, f32
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
    """``(mass_kg, full_thrust_N)`` as a controller has them: the mass from the config, and the
    thrust a field of 1.0 means from the hover thrust our vehicle serves (float32 over the
    parameter protocol: ``thrust_map``). ``sim`` gives its laws these, as a controller process
    gets them."""
    v = cfg.vehicle
    (hover,) = f32(hover_fraction(v.mass_kg, cfg.gravity_mps2, v.max_thrust_N))
    return v.mass_kg, full_thrust_N(v.mass_kg, cfg.gravity_mps2, hover)


class Uplink:
    """Follower ``i``'s setpoints as its vehicle takes them, in ``sim``: the controller's side
    (``link``: the thrust as a fraction of its full thrust, an ArduCopter's boost compensated)
    and the vehicle's (PX4's reading of the wire's fields, or ArduCopter's ``guided_command``
    with the ``GUID_OPTIONS`` bit 3 its controller sets): what a lockstep run carries, bit for
    bit."""

    def __init__(self, cfg: SwarmConfig, i: int):
        spec = cfg.vehicle_config(i)
        _, self.full_thrust_N = reported_vehicle_params(cfg)
        self.max_thrust_N = spec.max_thrust_N
        self.ardupilot: ArduCopterState | None = None
        if spec.autopilot == "ardupilot":
            self.ardupilot = ArduCopterState(hover_fraction(spec.mass_kg, spec.g_mps2, spec.max_thrust_N))
            self.ardupilot.set("GUID_OPTIONS", THRUST_AS_THRUST)

    def __call__(self, cmd: AttitudeCommand, ap: VehicleModel) -> AttitudeCommand:
        """What vehicle ``ap`` (in the state it is in now) holds for the controller's ``cmd``."""
        kept = self.ardupilot
        if kept is None:
            return command_roundtrip(cmd, self.full_thrust_N, self.max_thrust_N)
        if kept.angle_boost:
            cmd = cmd._replace(thrust_N=boost_compensated(float(cmd.thrust_N), cmd.q_c))
        fields = encode_attitude_target(cmd, self.full_thrust_N)
        held, _, why = guided_command(fields, 0, ap.command, ap.state, ap.params.max_thrust_N, kept)
        if held is None:
            raise ValueError(f"an ArduCopter refuses this setpoint: {why}")
        return held


def build_autopilot(cfg: SwarmConfig, i: int) -> VehicleModel:
    """Follower ``i``'s vehicle, built as its process builds it: from its config."""
    return build_vehicle(cfg.vehicle_config(i), i)
