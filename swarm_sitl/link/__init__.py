"""A controller's MAVLink link to its vehicle, in layers: ``transport`` (the datagrams each way,
signed, through a fault plan, with arrival stamps), ``decoding`` (the sample and the messages
read from them), ``setpoints`` (what is sent), ``handshake`` (the start-up with the autopilot),
``dialects`` (PX4's and ArduPilot's ways, told apart by the heartbeat), and ``vehicle_link`` (the
link a controller holds: the layers together).

May import: sim_vehicles.common, sim_vehicles.mavlink, sim_vehicles.runtime.
"""
