"""A follower flown by a ROS 2 node (``run --ros2-controller I``): its controller process runs
this in place of the law, so the vehicle link, the fault plan, the bus and the recording are
those of any other follower.

``Ros2Controller`` keeps the law's contract (``laws.contract.Law``): at each tick it publishes, on
ROS 2 topics in rmw_zenoh's layout (``ros2.wire``) under ``<ns>/follower_<i>/control/``, the
vehicle as sampled (``odom``, ``nav_msgs/msg/Odometry``; frame ``world`` ENU, the twist in the
body frame) and each in-neighbour's newest message (``from_<s>``,
``swarm_sitl_msgs/msg/Estimate``; its ``sender_position`` is zero: a law's inbox has the values and
their time, not where they came from), and it gives back what the ROS 2 node last published:
``setpoint`` (``swarm_sitl_msgs/msg/AttitudeSetpoint``), sent to the vehicle as
SET_ATTITUDE_TARGET, and ``message`` (``Estimate``), sent on the follower's out-edges. A setpoint
or message that does not decode, or has the wrong length or a non-finite value, is dropped and
counted (``dropped``).

- **Real time**: the run's clock does not wait for the node. Its answer to tick k flies from tick
  k + 1 on (one control period late, as a controller on another machine would be); until its
  first setpoint the vehicle is held level at hover thrust, and until its first message the
  out-neighbours get zeros.
- **Lockstep** (``lockstep``): the node answers each tick, as a law does: the bridge waits for the
  setpoint and the message stamped with the tick's odometry (the node's first answer within
  ``run.start_timeout_s``, the others within ``run.tick_timeout_s``, or the follower ends with one
  line naming the tick), and they fly at that tick. ``/clock`` (the leader's) may run ahead of a
  lockstep follower: a node answers the odometry's stamp, not the clock.
"""

import math
import time
from collections.abc import Mapping
from typing import Any

import numpy as np
import zenoh

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.common.quaternion import rotate_inverse
from swarm_sitl.laws.contract import LawContext, LawOutput, Received, VehicleSample
from swarm_sitl.ros2 import types, wire
from swarm_sitl.ros2.messages import Messages, stamp_ns
from swarm_sitl.ros2.publisher import Publisher

NODE = "swarm_sitl_follower_{i}"  #: the bridge's node name
SETPOINT = "swarm_sitl_msgs/msg/AttitudeSetpoint"
_NO_RATES = np.full(3, math.nan)
_AWAIT_POLL_S = 1e-4  #: lockstep: how often the bridge looks for the node's answer [s]


def control_topic(namespace: str, i: int, what: str) -> str:
    """Where follower ``i``'s ROS 2 controller meets the run: ``odom``, ``from_<s>`` (the run
    publishes them), ``setpoint``, ``message`` (the node does)."""
    return f"{namespace.rstrip('/')}/follower_{i}/control/{what}"


class Ros2Controller:
    """Follower ``ctx.follower_id``'s law, whose step is a ROS 2 node's (module docstring)."""

    record_fields: Mapping[str, int] = {}  # (the instance's: the swarm's law's, recorded as NaN)
    message_length: int = 0  # (the instance's: the swarm's law's)

    def __init__(
        self,
        ctx: LawContext,
        session: Any,
        r: Any,
        law: Any,
        answer_within_s: tuple[float, float] | None = None,
    ):
        """``r``: the config's ``ros2:`` section; ``law``: the swarm's law class, whose message
        length and record fields this keeps (the record: NaN, the law is the node's);
        ``answer_within_s``: lockstep, how long the node's first answer and each later one may
        take (None: real time, nothing is waited for)."""
        self.answer_within_s = answer_within_s
        self._answered = 0  #: ticks the node answered (lockstep)
        domain_id, namespace, distro = r.domain_id, r.namespace, r.distro
        self.ctx, self.distro = ctx, distro
        self.message_length = message_length = int(law.message_length)
        self.record_fields = dict(law.record_fields)
        self._record = np.full(sum(self.record_fields.values()), math.nan)
        i = ctx.follower_id
        self.dropped = 0
        zid = str(session.info.zid())
        node = NODE.format(i=i)
        self._m = Messages(distro)
        self._tokens = [
            session.liveliness().declare_token(wire.node_token(domain_id, zid, 0, namespace, node))
        ]
        outs = [("odom", types.ODOMETRY)] + [(f"from_{s}", types.ESTIMATE) for s in ctx.in_neighbours]
        self._pubs = {
            what: Publisher(
                session,
                domain_id,
                zid,
                namespace,
                node,
                n,
                control_topic(namespace, i, what),
                ros_type,
                distro,
            )
            for n, (what, ros_type) in enumerate(outs, start=1)
        }
        self._subs = {}
        for n, (what, ros_type) in enumerate(
            (("setpoint", SETPOINT), ("message", types.ESTIMATE)), start=len(outs) + 1
        ):
            topic, h = control_topic(namespace, i, what), types.type_hash(ros_type, distro)
            token = wire.publisher_token(
                domain_id, zid, 0, n, namespace, node, topic, ros_type, h, wire.Qos(), kind=wire.SUBSCRIPTION
            )
            self._tokens.append(session.liveliness().declare_token(token))
            key = wire.data_key(domain_id, topic, ros_type, h)
            self._subs[what] = (session.declare_subscriber(key, zenoh.handlers.RingChannel(1)), ros_type)
        hover = ctx.mass_kg * ctx.gravity_mps2
        self._command = AttitudeCommand(np.array([1.0, 0.0, 0.0, 0.0]), hover)
        self._message = np.zeros(message_length)

    def step(self, t_s: float, sample: VehicleSample, inbox: Mapping[int, Received]) -> LawOutput:
        if self.answer_within_s is None:
            self._take()  # (real time: its newest answer, to an earlier tick)
        m, i = self._m, self.ctx.follower_id
        pose = m.pose(sample.p_W, sample.q_WB)
        v_body = rotate_inverse(np.asarray(sample.q_WB, dtype=float), np.asarray(sample.v_W, dtype=float))
        for s, r in inbox.items():
            step = round(r.t_s / self.ctx.control_dt_s)
            self._put(f"from_{s}", m.estimate(r.t_s, s, i, step, np.zeros(3), r.values))
        self._put("odom", m.odometry(t_s, f"follower_{i}", pose, v_body, _NO_RATES))  # (not in the sample)
        if self.answer_within_s is not None:
            self._await(t_s)
        return LawOutput(self._command, self._message, self._record)

    def _await(self, t_s: float) -> None:
        """Lockstep: until the node's setpoint and message stamped ``t_s`` have come."""
        assert self.answer_within_s is not None  # (called in lockstep only)
        stamp = stamp_ns(t_s)
        first, later = self.answer_within_s
        within = first if self._answered == 0 else later
        end = time.monotonic() + within
        got = {"setpoint": False, "message": False}
        while True:
            for what, done in got.items():
                if not done:
                    got[what] = self._take_one(what, stamp)
            if all(got.values()):
                break
            if time.monotonic() > end:
                missing = " and its ".join(w for w, done in got.items() if not done)
                raise TimeoutError(
                    f"the ROS 2 node flying follower {self.ctx.follower_id} did not send its {missing} "
                    f"for t={t_s:.3f} s within {within:g} s (lockstep waits for its answer to each tick)"
                )
            time.sleep(_AWAIT_POLL_S)
        self._answered += 1

    def _take(self) -> None:
        """The node's newest setpoint and message, if any came since the last tick."""
        self._take_one("setpoint", None)
        self._take_one("message", None)

    def _take_one(self, what: str, stamp: tuple[int, int] | None) -> bool:
        """The node's newest ``what`` (``setpoint``, ``message``) taken, if one came (stamped
        ``stamp``, unless None); a bad one dropped and counted."""
        sub, ros_type = self._subs[what]
        sample = sub.try_recv()
        if sample is None:
            return False
        try:
            m = types.decode(sample.payload.to_bytes(), ros_type, self.distro)
        except Exception:
            self.dropped += 1
            return False
        if stamp is not None and (m.stamp.sec, m.stamp.nanosec) != stamp:
            return False  # (an answer to another tick)
        return self._setpoint(m) if what == "setpoint" else self._message_of(m)

    def _setpoint(self, m: Any) -> bool:
        q = np.array([m.orientation.w, m.orientation.x, m.orientation.y, m.orientation.z])
        rates = np.array([m.body_rate.x, m.body_rate.y, m.body_rate.z])
        n = float(np.linalg.norm(q))
        if not (
            np.all(np.isfinite(q)) and np.all(np.isfinite(rates)) and math.isfinite(m.thrust_n) and n > 0.5
        ):
            self.dropped += 1  # (not a finite attitude, rate and thrust)
            return False
        self._command = AttitudeCommand(q / n, float(m.thrust_n), rates)
        return True

    def _message_of(self, m: Any) -> bool:
        values = np.asarray(m.values, dtype=float)
        if values.shape != (self.message_length,) or not np.all(np.isfinite(values)):
            self.dropped += 1  # (not the law's message)
            return False
        self._message = values
        return True

    def _put(self, what: str, message: Any) -> None:
        self._pubs[what].put(message)

    def close(self) -> None:
        for sub, _ in self._subs.values():
            sub.undeclare()
        for pub in self._pubs.values():
            pub.close()
        for token in self._tokens:
            token.undeclare()
