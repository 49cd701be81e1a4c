"""MAVSDK (the native ``mavsdk`` 4.x binding from PyPI, unchanged) against a vehicle process.

It runs ``examples/fly_with_mavsdk.py`` (what `docs/tools.md` tells a user to run): MAVSDK's own flows,
discover the autopilot, read telemetry (position, attitude, armed, flight mode, health), arm, set
an attitude setpoint, ``offboard.start()``, tilt, ``offboard.stop()``; the vehicle must move as
commanded. Skipped, with the reason, where the package is not installed (the ``test`` extra
installs it where its wheels exist: Linux x86_64).
"""

import asyncio
import importlib.util
from pathlib import Path

import pytest

from tests.support import free_udp_port, spawn_vehicle

pytestmark = pytest.mark.system
pytest.importorskip(
    "mavsdk.asyncio", reason="MAVSDK is not installed (pip install '.[test]' on Linux x86_64)"
)
_spec = importlib.util.spec_from_file_location(
    "fly_with_mavsdk", Path(__file__).resolve().parents[1] / "examples" / "fly_with_mavsdk.py"
)
assert _spec is not None and _spec.loader is not None
example = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(example)


@pytest.mark.light
def test_mavsdk_reads_telemetry_and_flies_offboard_attitude():
    port = free_udp_port()
    proc = spawn_vehicle(1, port, "--duration", "60")
    try:
        seen = asyncio.run(asyncio.wait_for(example.fly(port), 60))
    finally:
        proc.terminate()
        proc.wait(timeout=10)
    hold, offboard = seen["modes"]
    p = seen["position"]
    assert p.latitude_deg == pytest.approx(47.397742) and p.longitude_deg == pytest.approx(8.545594)
    assert p.relative_altitude_m == pytest.approx(20.0, abs=0.01)
    assert seen["attitude"].yaw_deg == pytest.approx(90.0, abs=0.5)  # facing east: identity in ENU/FLU
    assert seen["armed"] is False and seen["armed_after"] is True
    assert seen["mode"] == hold and seen["mode_offboard"] == offboard and seen["mode_after"] == hold
    h = seen["health"]
    assert h.is_armable and h.is_global_position_ok and h.is_home_position_ok and h.is_local_position_ok
    north, east, down = seen["moved"]
    # 10 degrees nose down facing north (MAVSDK's yaw 0): about g tan(10 deg) = 1.7 m/s^2 north
    assert north > 3.0 and abs(east) < 0.3 * north and abs(down) < 1.0, seen["moved"]
    assert seen["attitude_tilted"].pitch_deg == pytest.approx(-10.0, abs=1.0)
    assert abs(seen["attitude_tilted"].yaw_deg) < 2.0
    assert seen["speed_held"] < 0.5  # Hold holds: it braked from about 5 m/s
