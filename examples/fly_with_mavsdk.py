"""Fly one simulated vehicle with MAVSDK, as a user of PX4 would (``pip install mavsdk``).

    python -m sim_vehicles --id 1 --port 14581 --position 0 0 20 &     # or swarm-sitl vehicles
    python examples/fly_with_mavsdk.py 14581

It reads the telemetry, arms, sends a level attitude setpoint, starts offboard (PX4 wants a
setpoint first), pitches 10 degrees nose down for 3 s (it flies north), stops offboard (back to
Hold) and prints what it saw. ``tests/test_tools_mavsdk.py`` runs this file.
"""

import asyncio
import math
import sys


async def _first(gen):
    async for x in gen:
        return x
    raise AssertionError("the subscription ended")


async def fly(port: int) -> dict:
    """Connect to the vehicle whose controller (or ground-station) port is ``port``, read its
    telemetry, arm, fly MAVSDK's offboard attitude flow (level, then 10 degrees nose down for 3 s),
    stop offboard (Hold: it brakes and holds); returns what it saw."""
    import mavsdk.asyncio as mavsdk
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
        await asyncio.sleep(4.0)  # Hold: it brakes and holds its position
        v = (await now(tel.subscribe_position_velocity_ned())).velocity
        seen["speed_held"] = math.sqrt(v.north_m_s**2 + v.east_m_s**2 + v.down_m_s**2)
        seen["moved"] = (end.north_m - start.north_m, end.east_m - start.east_m, end.down_m - start.down_m)
        seen["modes"] = (FlightMode.HOLD, FlightMode.OFFBOARD)
    return seen


def main() -> int:
    port = int(sys.argv[1]) if len(sys.argv) > 1 else 14581
    seen = asyncio.run(asyncio.wait_for(fly(port), 60))
    p = seen["position"]
    print(f"position {p.latitude_deg:.6f} N {p.longitude_deg:.6f} E, {p.relative_altitude_m:.2f} m up")
    print(f"armed {seen['armed']} -> {seen['armed_after']}")
    from mavsdk.plugins.telemetry import FlightMode

    modes = [FlightMode(seen[k]).name for k in ("mode", "mode_offboard", "mode_after")]
    print(f"flight mode {modes[0]} -> {modes[1]} -> {modes[2]}")
    h = seen["health"]
    print(f"health: armable {h.is_armable}, global position ok {h.is_global_position_ok}")
    north, east, down = seen["moved"]
    print(f"moved {north:.2f} m north, {east:.2f} m east, {down:.2f} m down in 3 s at 10 degrees nose down")
    print(f"4 s after offboard.stop() (Hold): {seen['speed_held']:.2f} m/s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
