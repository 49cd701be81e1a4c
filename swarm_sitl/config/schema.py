"""The one config schema of a swarm run: ``SwarmConfig`` and its sections, frozen and strict.

Unknown keys are errors. Cross-field checks (graph nodes exist and have a spanning tree from the
leader, rates divide evenly, unit quaternions, thrust above weight, the fault plan against the
graph and the duration) happen at validation, not mid-flight; ``load`` reads a file into one.
Two sections are defined where they are used: ``zenoh`` (``bus.session.ZenohSection``) and
``faults`` (``faults.plan.FaultPlan``).
"""

import dataclasses
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PrivateAttr,
    ValidationInfo,
    field_validator,
    model_validator,
)

from sim_vehicles.models import vehicle_config as vehicle_configs  # (a method below is vehicle_config)
from sim_vehicles.models.build import check as model_check
from swarm_sitl.bus.access import NodeKeys, node_keys
from swarm_sitl.bus.session import ZenohSection
from swarm_sitl.config.law_entry import resolve, validate_params
from swarm_sitl.config.ros2_section import Ros2Section
from swarm_sitl.config.seeds import STREAMS, derive_seeds, stream_seed, without_derived_seeds
from swarm_sitl.config.vehicle_section import SET_ELSEWHERE, VehicleSection, WindSection, spec_value
from swarm_sitl.faults.link_model import recorded
from swarm_sitl.faults.plan import FaultPlan
from swarm_sitl.laws.follower_law import HOLD_EXTRAPOLATE, HOLD_ZERO_ORDER, ControlGains
from swarm_sitl.laws.graph import Graph, GraphError
from swarm_sitl.laws.paper_gains import PaperGains
from swarm_sitl.laws.trajectories import FigureEight, Helix, Line, Trajectory
from swarm_sitl.laws.zou_meng import ZouMengParams
from swarm_sitl.specs.requirement import Requirement, SpecError

#: the default law: the paper's (``laws.zou_meng``)
PAPER_LAW = "swarm_sitl.laws.zou_meng:ZouMengLaw"


#: keys that moved from ``gains`` to ``vehicle`` (the paper's torque law is the vehicle's)
MOVED_TO_VEHICLE = ("l_q", "k_q")


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


Vec3 = tuple[float, float, float]
Positive = Annotated[float, Field(gt=0)]


class HelixSection(_Strict):
    type: Literal["helix"]  #: a circle in the horizontal plane that climbs at a constant rate
    radius_m: Positive  #: of the circle [m]
    #: about the vertical axis (positive: counter-clockwise seen from above) [rad/s]
    angular_rate_radps: float
    climb_rate_mps: float  #: vertical speed [m/s]
    center_m: Vec3 = (0.0, 0.0, 0.0)  #: centre of the circle at t = 0 [m; ENU]
    phase_rad: float = 0.0  #: angle on the circle at t = 0, from east [rad]

    def build(self) -> Trajectory:
        return Helix(
            self.radius_m, self.angular_rate_radps, self.climb_rate_mps, self.center_m, self.phase_rad
        )


class FigureEightSection(_Strict):
    type: Literal["figure_eight"]  #: a horizontal figure eight (lemniscate of Gerono)
    amplitude_x_m: Positive  #: east half-width [m]
    amplitude_y_m: Positive  #: north half-width [m]
    angular_rate_radps: Positive  #: of the east motion (the north one runs twice as fast) [rad/s]
    center_m: Vec3 = (0.0, 0.0, 0.0)  #: [m; ENU]

    def build(self) -> Trajectory:
        return FigureEight(self.amplitude_x_m, self.amplitude_y_m, self.angular_rate_radps, self.center_m)


class LineSection(_Strict):
    type: Literal["line"]  #: a straight line at constant velocity
    start_m: Vec3  #: position at t = 0 [m; ENU]
    velocity_mps: Vec3  #: [m/s; ENU]

    def build(self) -> Trajectory:
        return Line(self.start_m, self.velocity_mps)


class LeaderSection(_Strict):
    #: the leader's reference p_r(t), with its derivatives in closed form; ``type`` picks the kind
    trajectory: Annotated[HelixSection | FigureEightSection | LineSection, Field(discriminator="type")]


#: MAVLink's ``time_boot_ms`` is a uint32 count of ms: a run's ticks are stamped with it
MAX_STAMP_MS = 2**32 - 1


class RatesSection(_Strict):
    #: position loop / estimator exchange rate; at most 1000 Hz: each tick's MAVLink messages are
    #: stamped (and its faults drawn, and a lockstep vehicle stepped) by their whole ms
    control_hz: Annotated[float, Field(gt=0, le=1000)]
    #: attitude loop and plant integration rate
    attitude_hz: Annotated[float, Field(gt=0, allow_inf_nan=False)]
    estimator_substeps: Annotated[int, Field(ge=1, le=1000)] = 10  #: RK4 steps per control period

    @model_validator(mode="after")
    def _divides(self) -> "RatesSection":
        ratio = self.attitude_hz / self.control_hz
        if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
            raise ValueError(
                f"attitude_hz ({self.attitude_hz}) must be a whole multiple of control_hz ({self.control_hz})"
            )
        return self

    @property
    def attitude_steps_per_control(self) -> int:
        return round(self.attitude_hz / self.control_hz)


class GraphSection(_Strict):
    edges: list[tuple[int, int] | tuple[int, int, Positive]]  #: [src, dst] or [src, dst, weight]


class FollowerSection(_Strict):
    id: Annotated[int, Field(ge=1)]  #: 1..n, each once; the graph's node and the vehicle's MAVLink system id
    offset_m: Vec3  #: delta_i, desired position relative to the leader [m; ENU]
    initial_position_m: Vec3  #: [m; ENU]
    initial_velocity_mps: Vec3 = (0.0, 0.0, 0.0)  #: [m/s; ENU]
    initial_quaternion_wxyz: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)  #: body to world, unit
    #: the autopilot its vehicle speaks as, in place of ``vehicle.autopilot`` (a mixed swarm)
    autopilot: Literal["px4", "ardupilot"] | None = None
    #: a vehicle outside the run, started by you (a PX4 or ArduPilot SITL, a real one, ``swarm-sitl
    #: vehicles``): the pymavlink connection string its controller connects to
    #: (``udpin:0.0.0.0:14540``, ``tcp:127.0.0.1:5760``); the run starts no vehicle for it, and
    #: reads what it recorded only from the controller (``docs/autopilots.md``)
    mavlink: str | None = None

    @field_validator("initial_quaternion_wxyz")
    @classmethod
    def _unit(cls, q: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
        n = float(np.linalg.norm(q))
        if abs(n - 1.0) > 1e-6:
            raise ValueError(f"must be a unit quaternion, its norm is {n:.6g}")
        return q


class EstimatorSection(_Strict):
    #: the bracket inside gamma_ddot (docs/paper.md, erratum 7): ``sliding_surface`` weighs its acceleration
    #: sum by l_a, the form Theorem 1's proof and ``swarm-sitl check`` cover; ``printed`` is the
    #: paper's equation as printed (no l_a), which the theorem does not cover unless l_a = 1
    bracket: Literal["sliding_surface", "printed"] = "sliding_surface"
    sign_boundary_layer: Annotated[float, Field(ge=0)] = 0.0  #: 0 = paper's sgn; >0 saturation width
    #: how a neighbour's estimate is carried to the tick that uses it: ``extrapolate`` by its age
    #: with its own derivatives, ``zero_order`` as it came
    neighbour_hold: Literal["extrapolate", "zero_order"] = "extrapolate"
    #: a neighbour's latest estimate is used, carried by its age, while it is at most this old [s];
    #: past it the neighbour is left out of the sums until a newer one comes (a lost or cut edge)
    staleness_s: Positive = 0.5


class LawSection(_Strict):
    """The followers' control law (``laws.contract``; ``docs/laws.md`` shows how to write one)."""

    #: the law's class: ``"package.module:Name"`` (importable) or ``"path/to/file.py:Name"``
    #: (relative to the config file). The default is the paper's law, whose parameters are
    #: ``gains``, ``estimator`` and ``rates.estimator_substeps``
    entry: str = PAPER_LAW
    #: the law's own parameters, validated by its ``Params`` if it declares one
    params: dict[str, Any] = {}
    #: seeds each follower's ``LawContext.rng`` (with its id): the only randomness a law may use.
    #: Unset: the run's ``seed``
    seed: Annotated[int, Field(ge=0, lt=2**63)] = 0
    #: how much the process hosting the law (a controller, ``sim``) may grow while the law runs;
    #: past it the law's follower ends with one line (``nodes.law_guard``) [MB]
    max_memory_mb: Positive = 2000.0
    #: how much a law may print (to its controller's log; ``sim``: ``RUN_DIR/logs/laws.log``); the
    #: rest is dropped and counted [MB]
    max_output_mb: Annotated[float, Field(ge=0)] = 10.0

    @model_validator(mode="after")
    def _flies(self, info: ValidationInfo) -> "LawSection":
        if recorded(info):  # a run's record: read, never imported (``config.load.load_recorded``)
            return self
        cls = resolve(self.entry)
        if self.is_paper:
            if self.params:
                raise ValueError(
                    "params: the paper's law takes its parameters from gains, estimator and "
                    "rates.estimator_substeps; leave law.params empty"
                )
        else:
            validate_params(cls, self.params, self.entry)
        return self

    @property
    def is_paper(self) -> bool:
        return self.entry == PAPER_LAW


class SigningSection(_Strict):
    """MAVLink 2 signing of every vehicle link (``sim_vehicles.mavlink.signing``): unsigned or
    wrongly signed messages, and replays, are refused by vehicle and controller alike."""

    #: sign the links of the vehicles ``run`` spawns (off: for a tool that cannot sign)
    enabled: bool = True
    #: a file whose first line is the passphrase (the key is its SHA-256, as MAVProxy's ``signing
    #: setup`` and QGroundControl derive it). Unset: ``run`` writes a fresh random one to
    #: ``RUN_DIR/mavlink_signing.key`` (mode 0600); ``controllers`` and ``vehicles`` sign only with
    #: a file given here, the key the other side holds
    passphrase_file: str | None = None


class RunSection(_Strict):
    """Limits of a multi-process run (wall-clock seconds)."""

    start_timeout_s: Positive = 120.0  #: every process ready (connected, parameters read) within this
    #: how the vehicles and nodes are started: ``fork``ed from one process that has imported
    #: everything and loaded the compiled kernels (``running.fork_server``; Linux), or each ``spawn``ed as a
    #: new interpreter. Either way each is its own process with its own sockets.
    start: Literal["fork", "spawn"] = "fork"
    stall_timeout_s: Positive = 20.0  #: lockstep: a process waiting this long for an input gives up
    #: a law's step that does not return within this ends its follower with one line naming the law,
    #: the follower, the tick and the wait (``nodes.law_guard``; ``sim`` too). In real time a
    #: controller whose ticks stop this long is named as well, and a run ends at most this long
    #: after its duration. Less than ``stall_timeout_s``: the stalled follower is named, not those
    #: waiting on it. A law that compiles on its first step must do it within this, or when built
    tick_timeout_s: Positive = 10.0
    status_every: Annotated[int, Field(ge=1)] = 10  #: ticks between status messages of a controller
    lockstep_window: Annotated[int, Field(ge=1)] = 50  #: ticks the leader may run ahead in lockstep
    #: rate a controller asks its vehicle for ATTITUDE and HIGHRES_IMU, which it does not use [Hz]
    other_telemetry_hz: Annotated[float, Field(ge=0)] = 10.0
    #: real time: when the controllers tick within a period. ``staggered``: follower i at
    #: ``k * dt + (i - 1) / n * dt``, as flight computers with their own clocks would (on one host the
    #: controllers then share the CPU across the period instead of all waking at once);
    #: ``aligned``: all at ``k * dt``. Lockstep is always aligned (it must equal ``sim``).
    realtime_ticks: Literal["staggered", "aligned"] = "staggered"
    #: pass/fail bound: a follower whose formation error exceeds this after ``settle_s`` fails the
    #: run (exit 3, naming it and its stale inputs) [m]; none by default
    max_formation_error_m: Positive | None = None
    settle_s: Annotated[float, Field(ge=0)] = 20.0  #: the bound and the summary's peaks count from here [s]
    #: after a fault plan's restart of a controller or the leader, every follower that depends on
    #: it must be back within ``max_formation_error_m`` (0.1 m without one) this long after the
    #: restart, and stay there; one that is not is named, and fails a run with a bound
    #: (``docs/faults.md``, *Restarts*) [s]
    rejoin_within_s: Positive = 10.0
    #: a vehicle lost (a fault plan's kill) ends the run (exit 1 naming it); by default the rest
    #: of the swarm flies on and the loss is recorded
    stop_on_loss: bool = False

    @model_validator(mode="after")
    def _window(self) -> "RunSection":
        if self.tick_timeout_s >= self.stall_timeout_s:
            raise ValueError(
                f"tick_timeout_s ({self.tick_timeout_s:g}) must be less than stall_timeout_s "
                f"({self.stall_timeout_s:g}): a stalled law is named before those waiting on it give up"
            )
        if self.lockstep_window <= self.status_every:
            raise ValueError(
                f"lockstep_window ({self.lockstep_window}) must exceed status_every ({self.status_every}), "
                "or the leader waits for a status that never comes"
            )
        return self


class SwarmConfig(_Strict):
    name: Annotated[
        str, Field(pattern=r"^[A-Za-z0-9_-]+$")
    ]  #: the swarm's name: its zenoh keys and run directories
    duration_s: Positive  #: simulated time of a run [s]
    gravity_mps2: Positive = 9.81  #: g [m/s^2]
    rates: RatesSection  #: loop rates
    leader: LeaderSection  #: node 0, the reference
    graph: GraphSection  #: the directed communication graph (node 0 is the leader)
    vehicle: VehicleSection  #: every follower's airframe and autopilot
    followers: list[FollowerSection]  #: one per follower: its place in the formation and initial state
    gains: PaperGains  #: the paper's law's gains (section 4 for its example)
    #: the paper's estimator's sampled-time choices, and how long any law's inbox keeps a message
    estimator: EstimatorSection = EstimatorSection()
    law: LawSection = LawSection()  #: the followers' control law
    zenoh: ZenohSection = ZenohSection()  #: the bus between the processes
    signing: SigningSection = SigningSection()  #: MAVLink 2 signing of the vehicle links
    ros2: Ros2Section = Ros2Section()  #: the run on ROS 2 topics (off by default)
    run: RunSection = RunSection()  #: limits and pacing of a multi-process run
    faults: FaultPlan = FaultPlan()  #: what fails, how and when (``faults``)
    wind: WindSection = WindSection()  #: the air the vehicles fly in (still by default)
    #: requirements the run is held to (``specs.requirement``, ``docs/specs.md``): each judged with
    #: a robustness in ``summary.json``; one that fails makes the run exit 3, as the bound does
    spec: list[Requirement] = []
    #: the run's seed: every random stream (the fault plan's draws, the gusts, the sensor noise, the
    #: law's ``rng``) derives from it unless its section sets its own seed (``seeds.py``)
    seed: Annotated[int, Field(ge=0, lt=2**63)] = 0

    #: the random streams whose section sets its own seed (the others take the run's)
    _pinned: frozenset[str] = PrivateAttr(default=frozenset())
    #: read from a run directory (``config.load.load_recorded``): its plug-ins are not imported
    _recorded: bool = PrivateAttr(default=False)
    #: one line each on what the config says the old way (read, and how to write it now)
    _notices: list[str] = PrivateAttr(default_factory=list)

    @model_validator(mode="wrap")
    @classmethod
    def _moved_keys(cls, data: Any, handler: Any, info: ValidationInfo) -> "SwarmConfig":
        """``gains.l_q``, ``gains.k_q`` are the vehicle's now: read from there, with a notice."""
        moved: list[str] = []
        if isinstance(data, dict) and isinstance(data.get("gains"), dict):
            moved = [k for k in MOVED_TO_VEHICLE if k in data["gains"]]
            if moved:
                vehicle = dict(data["vehicle"]) if isinstance(data.get("vehicle"), dict) else {}
                for k in moved:
                    if k in vehicle and vehicle[k] != data["gains"][k]:
                        raise ValueError(f"gains.{k} and vehicle.{k} differ: give it once, as vehicle.{k}")
                    vehicle[k] = data["gains"][k]
                gains = {k: v for k, v in data["gains"].items() if k not in moved}
                data = {**data, "gains": gains, "vehicle": vehicle}
        data, pinned = derive_seeds(data)
        cfg = handler(data)
        cfg._pinned = pinned
        cfg._recorded = recorded(info)
        if moved:
            old, new = (", ".join(f"{where}.{k}" for k in moved) for where in ("gains", "vehicle"))
            them = "them" if len(moved) > 1 else "it"
            cfg._notices.append(f"{old}: the vehicle's attitude loop now, read as {new} (move {them} there)")
        return cfg

    @property
    def notices(self) -> list[str]:
        """What the config said the old way, one line each (``_moved_keys``)."""
        return list(self._notices)

    @model_validator(mode="after")
    def _cross(self, info: ValidationInfo) -> "SwarmConfig":
        ids = [f.id for f in self.followers]
        n = len(ids)
        if n == 0:
            raise ValueError("followers: at least one follower is needed")
        if sorted(ids) != list(range(1, n + 1)):
            raise ValueError(f"followers: ids must be 1..{n}, each once; got {ids}")
        try:
            self.build_graph()
        except GraphError as e:
            raise ValueError(f"graph: {e}") from None
        if self.duration_s * 1000 > MAX_STAMP_MS:
            raise ValueError(
                f"duration_s ({self.duration_s:g}) cannot be flown: MAVLink's time_boot_ms (uint32 ms) "
                f"wraps after {MAX_STAMP_MS / 1000:.3f} s (49.7 days)"
            )
        self.faults.check_against(self.graph_edges(), n, self.duration_s)
        if self.wind.enabled and self.vehicle.drag_Ns2pm2 == 0:
            raise ValueError("wind: the air pushes a vehicle through its drag: set vehicle.drag_Ns2pm2 > 0")
        if not self.vehicle.max_thrust_N > self.vehicle.mass_kg * self.gravity_mps2:
            raise ValueError(
                f"vehicle.max_thrust_N ({self.vehicle.max_thrust_N}) must exceed the weight "
                f"{self.vehicle.mass_kg * self.gravity_mps2:.3f} N"
            )
        for req in self.spec:
            try:
                req.check_against(ids, self.duration_s, self.graph_edges())
            except SpecError as e:
                raise ValueError(str(e)) from None
        if len({r.name for r in self.spec}) != len(self.spec):
            raise ValueError("spec: two requirements of one name")
        for i in self.ros2.controllers:
            if i not in ids:
                raise ValueError(f"ros2.controllers: no follower {i} (followers 1..{n})")
        if len(set(self.ros2.controllers)) != len(self.ros2.controllers):
            raise ValueError(f"ros2.controllers: a follower named twice ({self.ros2.controllers})")
        if recorded(info):
            return self
        try:  # the model and its parameters, as the vehicles will be built (cheap: no kernel runs)
            model_check(self.vehicle_config(ids[0]))
        except vehicle_configs.VehicleConfigError as e:
            raise ValueError(str(e).replace("vehicle config: ", "vehicle: ", 1)) from None
        return self

    # -- derived objects -------------------------------------------------------------------------
    @property
    def n_followers(self) -> int:
        return len(self.followers)

    def follower(self, i: int) -> FollowerSection:
        return next(f for f in self.followers if f.id == i)

    def tick_phase_s(self, i: int, lockstep: bool) -> float:
        """Where follower ``i``'s ticks fall within the control period [s] (``run.realtime_ticks``)."""
        if lockstep or self.run.realtime_ticks == "aligned":
            return 0.0
        return (i - 1) / self.n_followers * self.control_dt_s

    def build_graph(self) -> Graph:
        return Graph.from_edges(len(self.followers), [tuple(e) for e in self.graph.edges])

    def graph_edges(self) -> list[tuple[int, int]]:
        """``(src, dst)`` of every edge, in config order."""
        return [(int(e[0]), int(e[1])) for e in self.graph.edges]

    def node_keys(self, node: int) -> NodeKeys:
        """The zenoh keys node ``node`` uses (``bus.access``): its graph edges, and under a fault
        plan that kills processes the status and liveliness of its out-neighbours too."""
        return node_keys(self.build_graph(), node, watch=any(f.kill for f in self.faults.plan))

    def trajectory(self) -> Trajectory:
        return self.leader.trajectory.build()

    def vehicle_config(self, i: int) -> vehicle_configs.VehicleConfig:
        """Follower ``i``'s vehicle, whole (``sim_vehicles.models``): what ``sim`` builds and
        what the run hands its vehicle process as one file. Each field of the vehicle's config comes from the
        ``vehicle:`` key of its name (declared there or taken as it is), or from the section
        ``vehicle_section.SET_ELSEWHERE`` names; none is mapped by hand."""
        v, f = self.vehicle, self.follower(i)
        given = {**(v.model_extra or {}), **{k: getattr(v, k) for k in type(v).model_fields}}
        fields: dict[str, Any] = {}
        for field in dataclasses.fields(vehicle_configs.VehicleConfig):
            if field.name in SET_ELSEWHERE:
                value: Any = self
                for part in SET_ELSEWHERE[field.name].split("."):
                    value = f if part == "FOLLOWER" else getattr(value, part)
            elif field.name in given:
                value = given[field.name]
            else:
                continue  # the vehicle config's default
            fields[field.name] = spec_value(value)
        fields["autopilot"] = f.autopilot or v.autopilot  # a follower's own in place of the swarm's
        fields["params"] = {k: float(x) for k, x in v.params.items()}
        return vehicle_configs.VehicleConfig(**fields)

    def control_gains(self, mass_kg: float | None = None) -> ControlGains:
        """The paper's law's kernel parameters (``paper_law_params`` and the vehicle's)."""
        mass = self.vehicle.mass_kg if mass_kg is None else mass_kg
        return self.paper_law_params().control_gains(mass, self.gravity_mps2)

    def law_class(self) -> Any:
        """The followers' law (``law.entry``), imported once per process; not for a config read
        from a run directory (``is_recorded``: its law's interface is ``rundir.plugins``')."""
        if self._recorded:
            raise RuntimeError("a config read from a run directory does not import its law")
        return resolve(self.law.entry)

    @property
    def is_recorded(self) -> bool:
        """Read from a run directory (``config.load.load_recorded``): to read, not to fly."""
        return self._recorded

    def law_params(self) -> Any:
        """What the law's ``LawContext.params`` is: for the paper's law its gains and choices
        from this config's sections, for another its ``law.params`` through its ``Params``."""
        if not self.law.is_paper:
            return validate_params(self.law_class(), self.law.params, self.law.entry)
        return self.paper_law_params()

    def paper_law_params(self) -> ZouMengParams:
        """The paper's law's parameters from ``gains``, ``estimator`` and ``rates``."""
        g = self.gains
        return ZouMengParams(
            g,
            self.estimator.sign_boundary_layer,
            g.l_a if self.estimator.bracket == "sliding_surface" else 1.0,
            self.rates.estimator_substeps,
            self.hold,
        )

    @property
    def hold(self) -> int:
        return HOLD_EXTRAPOLATE if self.estimator.neighbour_hold == "extrapolate" else HOLD_ZERO_ORDER

    @property
    def control_dt_s(self) -> float:
        return 1.0 / self.rates.control_hz

    @property
    def n_control_steps(self) -> int:
        return round(self.duration_s * self.rates.control_hz)

    def gain_dict(self) -> dict[str, float]:
        return dict(self.gains.model_dump())

    def seed_streams(self) -> dict[str, tuple[int, bool]]:
        """Each random stream's seed, and whether its section pins it (else: the run's ``seed``)."""
        return {name: (int(stream_seed(self, name)), name in self._pinned) for name in STREAMS}

    def data(self) -> dict[str, Any]:
        """The config as plain data that validates to it again: the streams that take the run's
        seed are left so (their seeds not written), so another ``seed`` moves them all."""
        return without_derived_seeds(self.model_dump(mode="json"), self._pinned)
