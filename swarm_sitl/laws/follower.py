"""A follower's controller as a sampled-data system, and the leader's reference publisher.

Sampled-data semantics (the controller side; the same in ``sim`` and across processes):

- The controller ticks at ``control_rate_hz``; tick ``k`` is at ``t_k = k * dt`` (plus the
  follower's ``tick_phase_s`` in a staggered real-time run, ``config.schema.RunSpec.realtime_ticks``).
- At tick ``k`` it holds the estimate messages its in-neighbours sent at tick ``k - 1`` (their values
  at ``t_{k-1}``; none at ``k = 0``) and the sample of its own vehicle at ``t_k``. A neighbour with no
  message is left out of the sums (as if the edge were absent for that tick).
- Tick ``k``: (1) advance the controller state from ``t_{k-1}`` to ``t_k`` with those messages and
  the previous vehicle sample (carried from its own instant, which in real time may be older than
  ``t_{k-1}``), in ``substeps`` RK4 steps; (2) compute the command at ``t_k`` from the
  new state, the messages carried to ``t_k`` and the sample at ``t_k``; (3) emit its estimate at
  ``t_k`` for its out-neighbours (used at tick ``k + 1``) and the command for its vehicle (held until
  tick ``k + 1``).
- Messages and the vehicle sample are carried in time by the ``hold`` policy (``follower_law``):
  by default extrapolated by their age, which removes the one-period lag a zero-order hold adds per
  graph hop. In real time the sample used at ``t_k`` is up to a telemetry period old; it is carried
  to ``t_k`` the same way (position and velocity, with the acceleration commanded at the previous
  tick). In ``sim`` and lockstep it is taken at ``t_k`` and nothing is carried.
"""

from collections.abc import Mapping, Sequence
from typing import NamedTuple

import numpy as np

from sim_vehicles.common.command import AttitudeCommand
from swarm_sitl.laws.command_attitude import SingularCommandError
from swarm_sitl.laws.follower_law import (
    CTRL_SIZE,
    HOLD_EXTRAPOLATE,
    MSG_COLS,
    OUT_A_HAT,
    OUT_A_HAT_DOT,
    OUT_OMEGA_C,
    OUT_OMEGADOT_C,
    OUT_Q_C,
    OUT_THRUST,
    TICK_ACC,
    TICK_FINITE,
    TICK_OUT,
    TICK_STATE,
    ControlGains,
    controller_tick,
    gains_vector,
)
from swarm_sitl.laws.trajectories import Trajectory

#: a controller whose output is not finite and whose inputs are older than this many periods says
#: so: on a saturated machine in real time the estimator diverges on old estimates
STALE_INPUT_PERIODS = 5


class EstimateMessage(NamedTuple):
    """What node ``src`` tells its out-neighbours at tick ``step`` (the leader: its reference)."""

    src: int
    step: int
    t_s: float  #: time the values hold at [s]
    p_hat: np.ndarray  #: [m; world ENU]
    v_hat: np.ndarray  #: [m/s]
    a_hat: np.ndarray  #: [m/s^2]
    a_hat_dot: np.ndarray  #: [m/s^3]


class VehicleSample(NamedTuple):
    """What the controller knows of its own vehicle at one instant."""

    t_s: float
    p_W: np.ndarray  #: [m; world ENU]
    v_W: np.ndarray  #: [m/s; world ENU]
    q_WB: np.ndarray  #: [w,x,y,z; body FLU -> world ENU]


class ControllerStep(NamedTuple):
    command: AttitudeCommand
    estimate: EstimateMessage
    state: np.ndarray  #: controller state after the advance (``follower_law`` layout), at t_k
    output: np.ndarray  #: ``controller_output`` result (OUT_* layout)


class LeaderNode:
    """Node 0: publishes ``p_r`` and its derivatives as its 'estimate' (exact, so a_hat_dot = jerk)."""

    def __init__(self, trajectory: Trajectory, control_dt_s: float):
        self.trajectory = trajectory
        self.dt_s = control_dt_s

    def step(self, k: int) -> EstimateMessage:
        t = k * self.dt_s
        d = self.trajectory.derivatives(t)
        return EstimateMessage(0, k, t, d[0], d[1], d[2], d[3])


class FollowerController:
    """Estimator and position loop of one follower. No I/O: inputs in, command and estimate out."""

    def __init__(
        self,
        follower_id: int,
        offset_m: Sequence[float],
        in_edges: Sequence[tuple[int, float]],
        gains: ControlGains,
        control_dt_s: float,
        substeps: int,
        hold: int = HOLD_EXTRAPOLATE,
        max_thrust_N: float = float("inf"),
        tick_phase_s: float = 0.0,
    ):
        self.id = follower_id
        self.offset = np.asarray(offset_m, dtype=float)
        self.in_edges = tuple((int(s), float(w)) for s, w in in_edges)
        self.gains = gains
        self._gains_v = gains_vector(gains)
        self.dt_s = control_dt_s
        self.substeps = int(substeps)
        self.hold = int(hold)
        self.max_thrust_N = max_thrust_N
        self.tick_phase_s = float(tick_phase_s)  #: tick k is at k * dt + tick_phase_s
        self.state = np.zeros(CTRL_SIZE)
        self._prev_sample: VehicleSample | None = None
        self._prev_t = 0.0
        self._prev_acc = np.zeros(3)
        self._all_rows = np.empty((len(self.in_edges), MSG_COLS))

    def _rows(self, inbox: Mapping[int, EstimateMessage]) -> np.ndarray:
        """Message rows of the in-neighbours present in ``inbox`` (absent ones are left out)."""
        rows = self._all_rows
        n = 0
        for s, w in self.in_edges:
            m = inbox.get(s)
            if m is not None:
                r = rows[n]
                r[0] = w
                r[1] = m.t_s
                r[2:5] = m.p_hat
                r[5:8] = m.v_hat
                r[8:11] = m.a_hat
                r[11:14] = m.a_hat_dot
                n += 1
        return rows[:n]  # a view: the kernels read it and keep nothing

    def step(self, k: int, sample: VehicleSample, inbox: Mapping[int, EstimateMessage]) -> ControllerStep:
        """Tick ``k``: ``inbox`` holds the in-neighbours' messages of tick ``k - 1``."""
        t = k * self.dt_s + self.tick_phase_s
        msgs = self._rows(inbox)
        prev = self._prev_sample
        before = self.state
        n_sub = 0
        veh = sample if prev is None else prev
        if prev is not None:
            # from the previous tick to this one, at the configured internal step however long the
            # gap (a real-time tick skipped under load must not stretch the RK4 step)
            n_sub = self.substeps * max(1, round((t - self._prev_t) / self.dt_s))
        # real time: a sample older than the tick is carried to t_k under the acceleration
        # commanded since the last tick (as messages are carried by their age); else taken as is
        age = t - sample.t_s
        if not (age > 0.0 and self.hold == HOLD_EXTRAPOLATE and prev is not None):
            age = 0.0
        res = controller_tick(
            self.state,
            self._prev_t,
            t,
            n_sub,
            msgs,
            self.hold,
            veh.t_s,
            veh.p_W,
            veh.v_W,
            self._prev_acc,
            sample.p_W,
            sample.v_W,
            sample.q_WB,
            age,
            self.offset,
            self._gains_v,
            self.max_thrust_N,
        )
        self.state = res[TICK_STATE]
        out = res[TICK_OUT]
        if not res[TICK_FINITE]:
            ages = ", ".join(f"{t - r[1]:.3f}" for r in msgs)
            oldest = max([t - sample.t_s, *(t - r[1] for r in msgs)])
            behind = (
                f"; its inputs were up to {oldest:.2f} s old (in real time: a machine too slow for "
                f"the swarm, try fewer followers or lockstep; or a fault plan held them)"
                if oldest > STALE_INPUT_PERIODS * self.dt_s
                else ""
            )
            err = SingularCommandError(
                f"follower {self.id} at t={t:.3f}s: controller output is not finite (the estimator "
                f"diverged or the command force reached the singular set; see `swarm-sitl check`); "
                f"state finite: {bool(np.isfinite(self.state).all())}, sample age {t - sample.t_s:.3f} s, "
                f"message ages [{ages}] s{behind}"
            )
            err.inputs = {  # type: ignore[attr-defined]
                "t": t,
                "prev_t": self._prev_t,
                "state_before": before,
                "msgs": msgs.copy(),
                "sample": np.concatenate([[sample.t_s], sample.p_W, sample.v_W, sample.q_WB]),
                "prev_sample": np.concatenate([[prev.t_s], prev.p_W, prev.v_W, prev.q_WB, self._prev_acc])
                if prev is not None
                else np.zeros(0),
            }
            raise err
        thrust = float(out[OUT_THRUST])
        self._prev_sample = sample
        self._prev_t = t
        self._prev_acc = res[TICK_ACC]
        cmd = AttitudeCommand(
            q_c=out[OUT_Q_C], thrust_N=thrust, omega_c_B=out[OUT_OMEGA_C], omegadot_c_B=out[OUT_OMEGADOT_C]
        )
        x = self.state  # never mutated in place: each advance returns a new array
        est = EstimateMessage(self.id, k, t, x[0:3], x[3:6], out[OUT_A_HAT], out[OUT_A_HAT_DOT])
        return ControllerStep(cmd, est, x, out)
