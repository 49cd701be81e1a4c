"""A lockstep vehicle's usual tick in one compiled call.

In lockstep nearly every datagram a vehicle gets is the same: its controller's SET_ATTITUDE_TARGET
for the vehicle's current time, every field taken, while it flies offboard. The vehicle holds that
command for one period and sends its sample, LOCAL_POSITION_NED and ATTITUDE_QUATERNION of the new
state. Taken call by call in Python (the endpoint's setpoint handler, its step, its stream table,
a kernel call per frame) that was most of a vehicle's CPU, paid with cold caches at every wake-up
(``docs/performance.md``).

``step_and_sample`` runs the same kernels in the same order (``autopilot.advance_kernel``, then
``tick_frames``' two frames), so the state and the bytes are those of the general path bit for
bit. ``usual_tick`` decides, for the endpoint, when a tick is the usual one and keeps the books
around it (sequence numbers, stream schedule, ``.tlog``); anything else takes the endpoint's
general path, and so does every tick of a model other than the paper's (``plant.quad_x``: its
step is its own kernel, called through ``advance``).
"""

from typing import Any

import numpy as np

from sim_vehicles.common.jit import kernel
from sim_vehicles.mavlink import frames, tick_frames
from sim_vehicles.mavlink import px4_profile as px4
from sim_vehicles.mavlink.tick_frames import attitude_quaternion_into, local_position_into
from sim_vehicles.mavlink.wire_format import CMD_VALID, command_of
from sim_vehicles.plant.autopilot import Autopilot, advance_kernel
from sim_vehicles.vehicle.modes import MODE_OFFBOARD
from sim_vehicles.vehicle.port import ATTQ_ID, LPOS_ID

#: room for the two frames of a sample
SAMPLE_BYTES = 128
SP_VALID = tick_frames.SP_COMMAND.start + CMD_VALID  #: ``read_setpoint``'s command is valid


@kernel
def step_and_sample(x, plant_args, n_steps, out, seq, sysid, compid, lpos_spec, attq_spec, time_boot_ms):
    """Advance state ``x`` ``n_steps`` attitude steps under the command (``plant_args``:
    ``Autopilot.kernel_args``), then write LOCAL_POSITION_NED (sequence number ``seq``) and
    ATTITUDE_QUATERNION (``seq + 1``) of the new state, stamped ``time_boot_ms``, to ``out``.
    Returns the new state and the index after each frame."""
    x = advance_kernel(x, *plant_args, n_steps)
    end_lpos = local_position_into(out, 0, seq, sysid, compid, lpos_spec, time_boot_ms, x)
    end_attq = attitude_quaternion_into(out, end_lpos, seq + 1, sysid, compid, attq_spec, time_boot_ms, x)
    return x, end_lpos, end_attq


def usual_tick(ep: Any, r: np.ndarray) -> bool:
    """Take a setpoint (``tick_frames.read_setpoint``'s ``r``) to the endpoint ``ep``
    (``endpoint.VehicleEndpoint``) as a lockstep tick in one compiled call if it is the usual
    one: for this vehicle, stamped with its current time, every field taken and valid, the
    vehicle (the paper's model) armed in offboard, and nothing but the sample due when the period
    ends. The endpoint's books are kept as its ``_on_setpoint``, ``step`` and ``_stream`` keep
    them, and the state and frames are theirs bit for bit. False: not the usual tick (the
    endpoint's general path takes it)."""
    f = ep.flight
    # (else the general path's; a model other than the paper's has no one-call tick)
    plain = ep.sensors is None and ep.autopilot.wind is None and isinstance(ep.autopilot, Autopilot)
    if not (plain and ep._lockstep_steps and f.armed and f.mode == MODE_OFFBOARD):
        return False
    v = r.tolist()  # Python floats: cheaper to compare than numpy's scalars
    if not (
        v[tick_frames.SP_TYPE_MASK] == 0
        and v[SP_VALID]
        and ep._addressed(v[tick_frames.SP_TARGET_SYSTEM], v[tick_frames.SP_TARGET_COMPONENT])
    ):
        return False
    ap, port = ep.autopilot, ep.port
    streams = port.streams
    t0 = ap.time_s
    k1 = ap.step_index + ep._lockstep_steps
    t1 = k1 * ap.dt_s
    next_send = streams.next_send
    if not (
        v[tick_frames.SP_TIME_MS] == round(t0 * 1000)
        and t1 - t0 <= f.setpoint_timeout_s  # else its failsafe would begin: ``step``'s
        and t1 + 1e-9 < streams.next_other_s
        and next_send[LPOS_ID] <= t1 + 1e-9
        and next_send[ATTQ_ID] <= t1 + 1e-9
    ):
        return False
    port.accepted += 1
    port.accepted_from = (int(v[tick_frames.SP_SYSID]), int(v[tick_frames.SP_COMPID]))
    f.offboard_signal_s = f.last_setpoint_s = t0
    ep.stats.setpoints += 1
    ap.set_command(command_of(r[tick_frames.SP_COMMAND]), kernel_ready=True)  # views of ``r``
    assert isinstance(ap, Autopilot)  # (``plain``)
    out = ep._sample_out
    x, end_lpos, end_attq = step_and_sample(
        ap.state,
        ap.kernel_args,
        ep._lockstep_steps,
        out,
        port.mav.seq,
        ep.system_id,
        px4.AUTOPILOT,
        frames.LOCAL_POSITION_NED.spec,
        frames.ATTITUDE_QUATERNION.spec,
        round(t1 * 1000),
    )
    ap.state = x
    ap.step_index = k1
    port.take(out, end_lpos)
    port.take(out, end_attq, end_lpos)
    streams.sample_sent(t1)
    if ep._truth is not None:
        ep._truth.append((t1,), x)
    port.flush()
    ep._stream_gcs()
    return True
