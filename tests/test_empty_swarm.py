"""``empty_swarm``: a lockstep swarm's processes and messages with no work, as ``bench --empty`` runs it."""

import numpy as np
import pytest

from sim_vehicles.mavlink import frames, tick_frames
from sim_vehicles.mavlink.signing import Signer
from swarm_sitl.bench.empty_swarm import measure_empty, message_sizes


@pytest.mark.unit
def test_its_messages_are_the_size_of_a_signed_runs():
    """What the empty swarm sends is as long as what a signed lockstep run sends: a vehicle's
    sample (LOCAL_POSITION_NED and ATTITUDE_QUATERNION in one datagram), a controller's setpoint."""
    x = np.zeros(13)
    x[6] = 1.0
    out = np.zeros(tick_frames.FRAME_BYTES, np.uint8)
    n = tick_frames.pack_local_position(out, 0, 1, 1, frames.LOCAL_POSITION_NED.spec, 10, x)
    sample = out[:n].tobytes()
    n = tick_frames.pack_attitude_quaternion(out, 1, 1, 1, frames.ATTITUDE_QUATERNION.spec, 10, x)
    sample += out[:n].tobytes()
    n = tick_frames.pack_setpoint(
        out, 0, 1, 191, frames.SET_ATTITUDE_TARGET.spec, 10, 1, 1, x[6:10].copy(), x[10:13].copy(), 9.0, 25.0
    )
    setpoint = out[:n].tobytes()
    signer = Signer(bytes(32))
    assert message_sizes()[:2] == (len(signer.seal(sample)), len(signer.seal(setpoint)))


@pytest.mark.system
@pytest.mark.lockstep
def test_the_empty_paper_swarm_runs_every_tick_in_lockstep(paper_cfg):
    """Every vehicle answers every setpoint and every controller takes every payload of each
    in-neighbour up to its last tick (the one of the last tick may come after it stops)."""
    cfg = paper_cfg
    ticks = 200
    run = measure_empty(cfg, ticks)
    assert run.followers == 4 and run.wall_s > 0
    assert all(cpu > 0 for cpu in run.cpu_s.values()), run.cpu_s
    assert run.answered == dict.fromkeys((1, 2, 3, 4), ticks + 1)  # the first sample, then each setpoint
    ins = {i: sorted(s for s, d in cfg.graph_edges() if d == i) for i in (1, 2, 3, 4)}
    for i, got in run.received.items():
        assert sorted(int(s) for s in got) == ins[i]
        assert all(ticks <= n <= ticks + 1 for n in got.values()), (i, got)
