"""MAVSDK (the native ``mavsdk`` 4.x binding from PyPI, unchanged) against a vehicle process.

MAVSDK's own flows, as its examples use them: discover the autopilot, read telemetry (position,
attitude, armed, flight mode, health), arm, set an attitude setpoint, ``offboard.start()``, tilt,
``offboard.stop()``; the vehicle must move as commanded. Skipped, with the reason, where the
package is not installed (the ``test`` extra installs it where its wheels exist: Linux x86_64).
"""

import asyncio
import math

import pytest

from tests.test_vehicle_mavlink import _free_udp_port, spawn_vehicle

pytestmark = pytest.mark.system
mavsdk = pytest.importorskip(
    "mavsdk.asyncio", reason="MAVSDK is not installed (pip install '.[test]' on Linux x86_64)"
)


async def _first(gen):
    async for x in gen:
        return x
    raise AssertionError("the subscription ended")


async def _fly(port: int) -> dict:
    from mavsdk.asyncio.plugins.action import ActionAsync
    from mavsdk.asyncio.plugins.offboard import OffboardAsync
    from mavsdk.asyncio.plugins.telemetry import TelemetryAsync
    from mavsdk.plugins.offboard import Attitude
    from mavsdk.plugins.telemetry import FlightMode

    seen: dict = {}
    config = mavsdk.Configuration.create_with_component_type(mavsdk.ComponentType.GROUND_STATION)
    async with mavsdk.Mavsdk(config) as m:
        await m.add_any_connection(f"udpout://127.0.0.1:{port}")
        system = await m.first_autopilot(timeout_s=10.0)
        assert system is not None, "MAVSDK found no autopilot"
        tel, offboard, action = TelemetryAsync(system), OffboardAsync(system), ActionAsync(system)

        async def now(gen):
            return await asyncio.wait_for(_first(gen), 10)

        seen["position"] = await now(tel.subscribe_position())
        seen["attitude"] = await now(tel.subscribe_attitude_euler())
        seen["armed"] = await now(tel.subscribe_armed())
        seen["mode"] = await now(tel.subscribe_flight_mode())
        seen["health"] = await now(tel.subscribe_health())
        await action.arm()
        seen["armed_after"] = await now(tel.subscribe_armed())
        hover = 0.85 * 9.81 / 25.0
        await offboard.set_attitude(Attitude(0.0, 0.0, 0.0, hover))  # a setpoint before start, as PX4 needs
        await offboard.start()
        seen["mode_offboard"] = await now(tel.subscribe_flight_mode())
        start = (await now(tel.subscribe_position_velocity_ned())).position
        tilt = 10.0
        await offboard.set_attitude(Attitude(0.0, -tilt, 0.0, hover / math.cos(math.radians(tilt))))
        await asyncio.sleep(3.0)
        end = (await now(tel.subscribe_position_velocity_ned())).position
        seen["attitude_tilted"] = await now(tel.subscribe_attitude_euler())
        await offboard.stop()
        seen["mode_after"] = await now(tel.subscribe_flight_mode())
        seen["moved"] = (end.north_m - start.north_m, end.east_m - start.east_m, end.down_m - start.down_m)
        seen["modes"] = (FlightMode.HOLD, FlightMode.OFFBOARD)
    return seen


def test_mavsdk_reads_telemetry_and_flies_offboard_attitude():
    port = _free_udp_port()
    proc = spawn_vehicle(1, port, "--duration", "60")
    try:
        seen = asyncio.run(asyncio.wait_for(_fly(port), 60))
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
