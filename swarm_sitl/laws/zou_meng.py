"""The paper's law behind the law contract (``contract``): Zou & Meng's distributed estimator and
hierarchical position loop for one follower, ``law: {entry: "swarm_sitl.laws.zou_meng:ZouMengLaw"}``,
the default.

Its parameters are the config's ``gains`` (``paper_gains.PaperGains``),
``estimator`` (bracket, sign boundary layer, neighbour hold) and ``rates.estimator_substeps``
(``config.schema.SwarmConfig.law_params``); ``swarm-sitl check`` checks Theorem 1's conditions
for them. Its message is its estimate of the leader's state, ``[p_hat, v_hat, a_hat, a_hat_dot]``
(12 floats, ``REFERENCE``'s layout: the leader's own message is the exact one).

Per tick (``contract`` says what a tick is): (1) advance the controller state from the last tick
to this one with the messages and the previous vehicle sample (carried from its own instant,
which in real time may be older than the last tick), in ``substeps`` RK4 steps per period; (2)
compute the command at ``t`` from the new state, the messages carried to ``t`` and the sample;
(3) send the estimate at ``t``. Messages and the sample are carried by the ``hold`` policy
(``follower_law``): by default extrapolated by their age, which removes the one-period lag a
zero-order hold adds per graph hop. In real time the sample is up to a telemetry period old; it
is carried to ``t`` the same way (position and velocity, under the acceleration commanded at the
previous tick). In ``sim`` and lockstep it is taken at ``t`` and nothing is carried.
"""

from collections.abc import Mapping
from typing import NamedTuple

import numpy as np

from sim_vehicles.common.command import AttitudeCommand
from swarm_sitl.laws.command_attitude import SingularCommandError
from swarm_sitl.laws.contract import LawContext, LawOutput, Received, VehicleSample
from swarm_sitl.laws.follower_law import (
    CTRL_SIZE,
    HOLD_EXTRAPOLATE,
    MSG_COLS,
    OUT_A_HAT,
    OUT_OMEGA_C,
    OUT_OMEGADOT_C,
    OUT_Q_C,
    OUT_THRUST,
    OUT_U,
    OUT_U_DDOT,
    TICK_ACC,
    TICK_FINITE,
    TICK_OUT,
    TICK_STATE,
    ControlGains,
    controller_tick,
    gains_vector,
)
from swarm_sitl.laws.paper_gains import PaperGains

#: a controller whose output is not finite and whose inputs are older than this many periods says
#: so: on a saturated machine in real time the estimator diverges on old estimates
STALE_INPUT_PERIODS = 5

#: the recorded series: the controller state (``follower_law``'s layout, in this order), the
#: command force and its derivatives, and the acceleration estimate and its rate
RECORD_FIELDS = {
    "p_hat": 3,
    "v_hat": 3,
    "gamma": 3,
    "gamma_dot": 3,
    "eta": 3,
    "eta_dot": 3,
    "u": 3,
    "u_dot": 3,
    "u_ddot": 3,
    "a_hat": 3,
    "a_hat_dot": 3,
}
_FORCE = slice(OUT_U.start, OUT_U_DDOT.stop)  #: u, u_dot, u_ddot in ``controller_output``
_A_HAT = slice(OUT_A_HAT.start, OUT_A_HAT.start + 6)  #: a_hat, a_hat_dot in ``controller_output``


class ZouMengParams(NamedTuple):
    """The law's parameters: its gains (``paper_gains.PaperGains``) and how it is sampled."""

    gains: PaperGains
    sign_boundary_layer: float  #: 0 = the paper's sgn; > 0 = saturation width (deviation)
    bracket_a_weight: float  #: l_a = the sliding-surface bracket Theorem 1 covers, 1 = as printed
    substeps: int = 10  #: RK4 steps of the controller state per control period
    hold: int = HOLD_EXTRAPOLATE  #: ``follower_law.HOLD_*``: how messages are carried to a tick

    def control_gains(self, mass_kg: float, gravity_mps2: float) -> ControlGains:
        """The kernels' parameters: the gains, by name, the sampling choices and the vehicle's
        mass and g."""
        return ControlGains(
            **self.gains.model_dump(),
            sign_boundary_layer=self.sign_boundary_layer,
            bracket_a_weight=self.bracket_a_weight,
            mass_kg=mass_kg,
            g_mps2=gravity_mps2,
        )


class ZouMengLaw:
    """Estimator and position loop of one follower. No I/O: inputs in, command and estimate out."""

    message_length = 12
    record_fields = RECORD_FIELDS
    Params = ZouMengParams

    def __init__(self, ctx: LawContext):
        p: ZouMengParams = ctx.params
        self.id = ctx.follower_id
        self.offset = np.asarray(ctx.offset_m, dtype=float)
        self.weights = tuple((int(s), float(w)) for s, w in ctx.in_edges)
        self.gains = p.control_gains(ctx.mass_kg, ctx.gravity_mps2)
        self._gains_v = gains_vector(self.gains)
        self.dt_s = ctx.control_dt_s
        self.substeps = int(p.substeps)
        self.hold = int(p.hold)
        self.max_thrust_N = ctx.max_thrust_N
        self.state = np.zeros(CTRL_SIZE)
        self._prev_sample: VehicleSample | None = None
        self._prev_t = 0.0
        self._prev_acc = np.zeros(3)
        self._all_rows = np.empty((len(self.weights), MSG_COLS))

    def _rows(self, inbox: Mapping[int, Received]) -> np.ndarray:
        """Message rows ``[weight, t_s, p, v, a, a_dot]`` of the in-neighbours present in
        ``inbox`` (absent ones are left out of the sums, as if the edge were absent)."""
        rows = self._all_rows
        n = 0
        for s, w in self.weights:
            m = inbox.get(s)
            if m is not None:
                r = rows[n]
                r[0] = w
                r[1] = m.t_s
                r[2:14] = m.values
                n += 1
        return rows[:n]  # a view: the kernels read it and keep nothing

    def step(self, t: float, sample: VehicleSample, inbox: Mapping[int, Received]) -> LawOutput:
        msgs = self._rows(inbox)
        prev = self._prev_sample
        before = self.state
        n_sub = 0
        veh = sample if prev is None else prev
        if prev is not None:
            # from the previous tick to this one, at the configured internal step however long the
            # gap (a real-time tick skipped under load must not stretch the RK4 step)
            n_sub = self.substeps * max(1, round((t - self._prev_t) / self.dt_s))
        # real time: a sample older than the tick is carried to t under the acceleration
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
            raise self._not_finite(t, sample, msgs, before, prev)
        self._prev_sample = sample
        self._prev_t = t
        self._prev_acc = res[TICK_ACC]
        cmd = AttitudeCommand(out[OUT_Q_C], float(out[OUT_THRUST]), out[OUT_OMEGA_C], out[OUT_OMEGADOT_C])
        x = self.state  # never mutated in place: each advance returns a new array
        message = np.concatenate((x[0:6], out[_A_HAT]))
        return LawOutput(cmd, message, np.concatenate((x, out[_FORCE], out[_A_HAT])))

    def _not_finite(
        self,
        t: float,
        sample: VehicleSample,
        msgs: np.ndarray,
        before: np.ndarray,
        prev: VehicleSample | None,
    ) -> SingularCommandError:
        """The error of a tick whose output is not finite, with what it was given (``inputs``:
        the controller process saves them, to reproduce the tick offline)."""
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
        return err
