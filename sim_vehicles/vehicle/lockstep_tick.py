"""A lockstep vehicle's usual tick in one compiled call.

In lockstep nearly every datagram a vehicle gets is the same: its controller's SET_ATTITUDE_TARGET
for the vehicle's current time, every field taken, while it flies offboard. The vehicle holds that
command for one period and sends its sample, LOCAL_POSITION_NED and ATTITUDE_QUATERNION of the new
state. Taken call by call in Python (the endpoint's setpoint handler, its step, its stream table,
a kernel call per frame) that was most of a vehicle's CPU, paid with cold caches at every wake-up
(``docs/performance.md``).

``step_and_sample`` runs the same kernels in the same order (``autopilot.advance_kernel``, then
``tick_frames``' two frames), so the state and the bytes are those of the general path bit for
bit. ``endpoint`` decides when a tick is the usual one and keeps the books around it
(sequence numbers, stream schedule, ``.tlog``); anything else takes the general path.
"""

from sim_vehicles.common.jit import kernel
from sim_vehicles.mavlink.tick_frames import attitude_quaternion_into, local_position_into
from sim_vehicles.plant.autopilot import advance_kernel

#: room for the two frames of a sample
SAMPLE_BYTES = 128


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
