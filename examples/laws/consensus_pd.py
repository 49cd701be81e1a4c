"""Consensus tracking of the leader's state with a PD position loop and geometric thrust/attitude
extraction: a distributed formation-tracking law that is not Zou & Meng's, written as a user of
swarm-sitl writes one (only ``swarm_sitl.laws.contract``, numpy and pydantic).

Config: ``law: {entry: "../examples/laws/consensus_pd.py:ConsensusPD", params: {...}}``
(``configs/consensus_pd.yaml`` flies it on the paper's scenario).

**Estimator** (W. Ren, "Multi-vehicle consensus with a time-varying reference state", Systems &
Control Letters 56(7-8):474-483, 2007, Section 4, the double-integrator consensus tracking
algorithm; W. Ren and R. W. Beard, *Distributed Consensus in Multi-vehicle Cooperative Control*,
Springer 2008, Ch. 4). Each follower ``i`` keeps an estimate ``(p_i, v_i)`` of the leader's
position and velocity and drives it with

    a_i = (1 / kappa_i) sum_j a_ij [ a_j - alpha (p_i - p_j) - gamma (v_i - v_j) ],
    kappa_i = sum_j a_ij,          p_i' = v_i,   v_i' = a_i,

over its in-neighbours ``j`` (``j = 0``: the leader's own ``p_r, v_r, a_r``); it sends
``[p_i, v_i, a_i]`` (9 floats). In continuous time, with ``M = L + diag(a_i0)`` nonsingular (a
spanning tree rooted at the leader), stacking the errors ``e_i = p_i - p_r`` gives
``M (e'' + gamma e' + alpha e) = 0``, so every follower's error obeys ``e'' + gamma e' + alpha e
= 0`` whatever the graph: it decays for any ``alpha, gamma > 0`` (``tests``: this identity, and
the closed-form decay). Sampled at the control period, a neighbour's message is carried to the
tick by its age (``p + v age + a age^2 / 2``; the leader's also with its jerk), the estimate is
advanced between ticks under constant ``a_i`` (exact for a double integrator), and a follower
that hears nobody (a cut edge past ``estimator.staleness_s``) coasts on its last ``a_i``.

**Position loop** (PD with feedforward): ``a_c = a_i + k_p (p_i + delta_i - p) + k_v (v_i - v)``,
its norm limited to ``max_accel_mps2``, and the command force ``F = m (a_c + g e3)``; ``p`` is the
vehicle's sample carried to the tick by its velocity (in real time a sample is up to a telemetry
period old; in ``sim`` and lockstep it is the tick's own).

**Thrust and attitude** (T. Lee, M. Leok, N. H. McClamroch, "Geometric tracking control of a
quadrotor UAV on SE(3)", IEEE CDC 2010, eq. (12)-(15)): ``b3c = F / |F|``, ``b1c`` the heading
``[cos psi, sin psi, 0]`` projected normal to ``b3c``, ``R_c = [b1c, b3c x b1c, b3c]``; the
thrust is ``F . R e3`` with the vehicle's attitude ``R`` (no thrust along a tilt it has not
reached yet), limited to ``[0, max_thrust]``. No body-rate feedforward: the vehicle's attitude
loop tracks ``R_c`` with zero commanded rates.
"""

from collections.abc import Mapping
from typing import ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from swarm_sitl.laws.contract import (
    REFERENCE,
    AttitudeCommand,
    LawContext,
    LawOutput,
    Received,
    VehicleSample,
)

E3 = np.array([0.0, 0.0, 1.0])


class ConsensusPDParams(BaseModel):
    model_config = ConfigDict(extra="forbid")

    alpha: float = Field(4.0, gt=0, description="consensus gain on position estimates [1/s^2]")
    gamma: float = Field(4.0, gt=0, description="consensus gain on velocity estimates [1/s]")
    k_p: float = Field(4.0, gt=0, description="position gain of the PD loop [1/s^2]")
    k_v: float = Field(4.0, gt=0, description="velocity gain of the PD loop [1/s]")
    max_accel_mps2: float = Field(5.0, gt=0, description="largest commanded acceleration [m/s^2]")
    yaw_rad: float = Field(0.0, description="heading the vehicles hold [rad, from east]")


def carried(values: np.ndarray, age_s: float, leader: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A message's ``(p, v, a)`` carried forward by its age (the leader's also by its jerk)."""
    p, v, a = values[0:3], values[3:6], values[6:9]
    if leader:
        j = values[REFERENCE["j_r"]]
        return (
            p + age_s * v + age_s**2 / 2 * a + age_s**3 / 6 * j,
            v + age_s * a + age_s**2 / 2 * j,
            a + age_s * j,
        )
    return p + age_s * v + age_s**2 / 2 * a, v + age_s * a, a


def consensus_acceleration(
    p: np.ndarray,
    v: np.ndarray,
    neighbours: list[tuple[float, np.ndarray, np.ndarray, np.ndarray]],
    alpha: float,
    gamma: float,
) -> np.ndarray | None:
    """Ren's ``a_i`` from the neighbours' ``(weight, p_j, v_j, a_j)``; ``None`` if there are none."""
    kappa = sum(w for w, *_ in neighbours)
    if not neighbours or kappa <= 0.0:
        return None
    acc = np.zeros(3)
    for w, pj, vj, aj in neighbours:
        acc += w * (aj - alpha * (p - pj) - gamma * (v - vj))
    return acc / kappa


def rotation(q: np.ndarray) -> np.ndarray:
    """The rotation matrix of a Hamilton quaternion ``[w, x, y, z]`` (body -> world)."""
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def quaternion(R: np.ndarray) -> np.ndarray:
    """The unit quaternion ``[w, x, y, z]`` (``w >= 0``) of a rotation matrix (Shepperd's method)."""
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    k = int(np.argmax([tr, R[0, 0], R[1, 1], R[2, 2]]))
    if k == 0:
        s = 2.0 * np.sqrt(1.0 + tr)
        q = np.array([s / 4, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s])
    elif k == 1:
        s = 2.0 * np.sqrt(1.0 + 2 * R[0, 0] - tr)
        q = np.array([(R[2, 1] - R[1, 2]) / s, s / 4, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s])
    elif k == 2:
        s = 2.0 * np.sqrt(1.0 + 2 * R[1, 1] - tr)
        q = np.array([(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, s / 4, (R[1, 2] + R[2, 1]) / s])
    else:
        s = 2.0 * np.sqrt(1.0 + 2 * R[2, 2] - tr)
        q = np.array([(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, s / 4])
    q = q if q[0] >= 0 else -q
    return q / np.linalg.norm(q)


def thrust_and_attitude(F: np.ndarray, R: np.ndarray, yaw_rad: float) -> tuple[float, np.ndarray]:
    """Lee et al.'s ``(F . R e3, R_c)`` for the command force ``F`` (world), attitude ``R``, heading."""
    b3 = F / np.linalg.norm(F)
    b1d = np.array([np.cos(yaw_rad), np.sin(yaw_rad), 0.0])
    b2 = np.cross(b3, b1d)
    b2 /= np.linalg.norm(b2)
    b1 = np.cross(b2, b3)
    return float(F @ R[:, 2]), np.column_stack((b1, b2, b3))


class ConsensusPD:
    message_length: ClassVar[int] = 9  #: [p_i, v_i, a_i], the follower's estimate of the leader's state
    record_fields: ClassVar[dict[str, int]] = {"p_hat": 3, "v_hat": 3, "a_hat": 3, "a_c": 3, "heard": 1}
    Params = ConsensusPDParams

    def __init__(self, ctx: LawContext):
        self.p: ConsensusPDParams = ctx.params
        self.weights = dict(ctx.in_edges)
        self.offset = np.asarray(ctx.offset_m, dtype=float)
        self.mass_kg = ctx.mass_kg
        self.g = ctx.gravity_mps2
        self.max_thrust_N = ctx.max_thrust_N
        self.zero = np.zeros(3)
        self.t_s: float | None = None  # the estimate's instant; None before the first tick
        self.p_hat = np.zeros(3)
        self.v_hat = np.zeros(3)
        self.a_hat = np.zeros(3)

    def step(self, t_s: float, sample: VehicleSample, inbox: Mapping[int, Received]) -> LawOutput:
        prm = self.p
        if self.t_s is None:  # start from where the formation would put the leader
            self.p_hat = sample.p_W - self.offset
            self.v_hat = sample.v_W.copy()
        else:  # advance the estimate to t_s under constant a_hat (exact for p'' = a)
            h = t_s - self.t_s
            self.p_hat = self.p_hat + h * self.v_hat + h * h / 2 * self.a_hat
            self.v_hat = self.v_hat + h * self.a_hat
        self.t_s = t_s
        heard = [(self.weights[j], *carried(m.values, m.age_s, j == 0)) for j, m in sorted(inbox.items())]
        a = consensus_acceleration(self.p_hat, self.v_hat, heard, prm.alpha, prm.gamma)
        p = sample.p_W + (t_s - sample.t_s) * sample.v_W  # real time: the sample carried to the tick
        if a is not None:
            self.a_hat = a
        a_c = self.a_hat + prm.k_p * (self.p_hat + self.offset - p) + prm.k_v * (self.v_hat - sample.v_W)
        norm = float(np.linalg.norm(a_c))
        if norm > prm.max_accel_mps2:
            a_c = a_c * (prm.max_accel_mps2 / norm)
        F = self.mass_kg * (a_c + self.g * E3)
        thrust, R_c = thrust_and_attitude(F, rotation(sample.q_WB), prm.yaw_rad)
        thrust = min(max(thrust, 0.0), self.max_thrust_N)
        command = AttitudeCommand(quaternion(R_c), thrust, self.zero, self.zero)
        message = np.concatenate((self.p_hat, self.v_hat, self.a_hat))
        record = {
            "p_hat": self.p_hat,
            "v_hat": self.v_hat,
            "a_hat": self.a_hat,
            "a_c": a_c,
            "heard": len(heard),
        }
        return LawOutput(command, message, record)
