"""A follower's law as the bench runs it: its inputs made, its outputs checked, its record laid out.

``HostedLaw.step`` is what ``sim`` and the controller process call each tick with the law's inbox
(``Received``: values, instant, age; ``nodes.neighbour_inbox`` makes it), calls the law, and checks what
came back against the contract (``laws.contract``): a command with a unit quaternion and finite
thrust and rates, a message of the declared length with finite values, a record of the declared
fields. Anything else, and anything the law raises, is a ``LawError``: one line naming the law,
the follower and the tick.

The record of a tick is flat, in ``record_fields``' order (``rundir.recording.layout``); the
recording puts the command before it (``rundir.recording.COMMAND_FIELDS``).
"""

import contextlib
import math
import os
from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np

from sim_vehicles.common.command import AttitudeCommand
from swarm_sitl.laws.contract import REFERENCE_LENGTH, LawOutput, Received, VehicleSample
from swarm_sitl.nodes.law_guard import LawExit, LawGuard, LawStopped
from swarm_sitl.rundir.recording import layout

#: how far a command quaternion's norm may be from 1 (the vehicle refuses it beyond)
UNIT_TOLERANCE = 1e-3


class LawError(RuntimeError):
    """A law broke the contract or raised; the message is one line naming the law and the follower."""


def law_name(law: Any) -> str:
    cls = type(law)
    return f"{cls.__module__}:{cls.__qualname__}"


def one_line(e: BaseException) -> str:
    text = " ".join(str(e).split())
    return f"{type(e).__name__}: {text}" if text else type(e).__name__


class HostedStep(NamedTuple):
    command: AttitudeCommand
    message: np.ndarray  #: the law's message, float64, checked
    record: np.ndarray  #: the law's record, flat (``recording.layout``); reused by the next tick


class HostedLaw:
    """Follower ``follower_id``'s ``law``, stepped through the contract."""

    def __init__(self, law: Any, follower_id: int, name: str | None = None):
        self.law = law
        self.id = follower_id
        self.name = law_name(law) if name is None else name  #: as the config's ``law.entry`` says
        self.message_length = int(law.message_length)
        self.layout = layout(law.record_fields)
        self.record_width = sum(s.stop - s.start for s in self.layout.values())
        self._record = np.zeros(self.record_width)
        self._step = law.step
        #: what stops a step that hangs, exits or floods (``law_guard``); None: unguarded (the paper's)
        self.guard: LawGuard | None = None

    def _fail(self, t: float, what: str) -> LawError:
        return LawError(f"law {self.name}, follower {self.id} at t={t:.3f} s: {what}")

    def step(self, t: float, sample: VehicleSample, inbox: Mapping[int, Received]) -> HostedStep:
        """Tick ``t`` with the newest usable message of each in-neighbour (``inbox``)."""
        guard = self.guard
        try:
            if guard is not None:
                guard.enter(self.name, self.id, t)
            out = self._step(t, sample, inbox)
            if guard is not None:
                guard.after_step()  # (the step that took the memory past its bound is the one named)
        except LawStopped as e:
            raise self._fail(t, str(e) or (guard.stop_reason if guard else "stopped")) from None
        except LawExit as e:
            raise self._fail(t, f"it called os._exit({e.code}), which ends nothing here") from None
        except SystemExit as e:
            raise self._fail(t, f"it called sys.exit({e.code!r}), which ends nothing here") from None
        except Exception as e:
            raise self._fail(t, one_line(e)) from e
        finally:
            if guard is not None:
                guard.leave()
        if type(out) is not LawOutput and not (isinstance(out, tuple) and len(out) == 3):
            raise self._fail(
                t, f"step returned {type(out).__name__}, not a LawOutput(command, message, record)"
            )
        cmd, message, record = out
        if type(cmd) is not AttitudeCommand:
            raise self._fail(t, f"its command is {type(cmd).__name__}, not an AttitudeCommand")
        if (
            type(message) is not np.ndarray
            or message.dtype != np.float64
            or message.shape != (self.message_length,)
        ):
            message = self._message(t, message)
        try:  # as Python floats: cheaper than numpy calls on arrays this small
            qw, qx, qy, qz = cmd.q_c.tolist()
            w = cmd.omega_c_B.tolist()
            wd = cmd.omegadot_c_B.tolist()
            thrust = float(cmd.thrust_N)
            ok = (
                abs(qw * qw + qx * qx + qy * qy + qz * qz - 1.0) <= UNIT_TOLERANCE
                and math.isfinite(thrust)
                and len(w) == 3
                and len(wd) == 3
                and all(map(math.isfinite, w))
                and all(map(math.isfinite, wd))
                and all(map(math.isfinite, message.tolist()))
            )
        except (AttributeError, TypeError, ValueError):
            raise self._fail(t, self._bad_shapes(cmd)) from None
        if not ok:
            raise self._fail(t, self._bad_output(cmd, message))
        return HostedStep(cmd, message, self._flat(t, record))

    def _message(self, t: float, message: Any) -> np.ndarray:
        try:
            m = np.asarray(message, dtype=np.float64)
        except (TypeError, ValueError):
            raise self._fail(t, f"its message is not numbers ({type(message).__name__})") from None
        if m.shape != (self.message_length,):
            raise self._fail(
                t, f"its message has shape {m.shape}, it declares message_length {self.message_length}"
            )
        return m

    @staticmethod
    def _bad_shapes(cmd: AttitudeCommand) -> str:
        shapes = ", ".join(
            f"{name} {getattr(v, 'shape', type(v).__name__)}"
            for name, v in (
                ("q_c", cmd.q_c),
                ("omega_c_B", cmd.omega_c_B),
                ("omegadot_c_B", cmd.omegadot_c_B),
            )
        )
        return (
            f"its command's q_c, omega_c_B, omegadot_c_B must be arrays of 4, 3, 3 floats and "
            f"thrust_N a float (got {shapes}, thrust_N {type(cmd.thrust_N).__name__})"
        )

    def _bad_output(self, cmd: AttitudeCommand, message: np.ndarray) -> str:
        q, w, wd = cmd.q_c, cmd.omega_c_B, cmd.omegadot_c_B
        if w.shape != (3,) or wd.shape != (3,):
            return self._bad_shapes(cmd)
        if not np.isfinite(message).all():
            return "its message is not finite"
        if not (
            math.isfinite(cmd.thrust_N)
            and np.isfinite(q).all()
            and np.isfinite(w).all()
            and np.isfinite(wd).all()
        ):
            return f"its command is not finite (thrust {cmd.thrust_N}, q_c {q}, omega_c {w}, omegadot_c {wd})"
        return f"its command's q_c {q} is not a unit quaternion (norm {np.linalg.norm(q):.6g})"

    def _flat(self, t: float, record: Any) -> np.ndarray:
        if type(record) is np.ndarray and record.shape == (self.record_width,):
            return record
        flat = self._record
        if isinstance(record, Mapping):
            if len(record) != len(self.layout) or not all(name in record for name in self.layout):
                extra = sorted(set(record) - set(self.layout))
                missing = sorted(set(self.layout) - set(record))
                raise self._fail(t, f"its record has fields {extra} it does not declare, lacks {missing}")
            for name, at in self.layout.items():
                value = record[name]
                width = at.stop - at.start
                try:
                    if np.size(value) != width:  # no broadcasting of one value over a field
                        raise ValueError
                    flat[at] = value
                except (TypeError, ValueError):
                    raise self._fail(t, f"its record field {name!r} is not {width} number(s)") from None
            return flat
        shape = getattr(record, "shape", type(record).__name__)
        raise self._fail(t, f"its record is {shape}, not a mapping or an array of {self.record_width}")


def warm_up(law: Any, sample: VehicleSample, sources: list[int], message_length: int) -> None:
    """Two ticks of a scratch law on still inputs, so compiled code loads before the first real
    tick; a law that cannot step on them is left to fail, if it does, at its real tick. What the
    scratch ticks print is not the law's output: it is dropped."""
    z = np.zeros(REFERENCE_LENGTH)
    inbox = {s: Received(z if s == 0 else np.zeros(message_length), 0.0, 0.0) for s in sources}
    dt = 0.01
    with open(os.devnull, "w") as null, contextlib.redirect_stdout(null), contextlib.redirect_stderr(null):
        for k in range(2):
            try:
                law.step(k * dt, sample._replace(t_s=k * dt), inbox)
            except Exception:
                return
