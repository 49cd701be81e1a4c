"""The simulated aircraft, pure: its parameters (``params``), the 6-DOF rigid body
(``rigid_body``), the paper's torque law (``torque_law``), the attitude loop that holds a command
(``autopilot``), what it flies when its setpoints stop (``failsafe``), what it reports of its
state (``sensors``: latency and noise) and the air it flies in (``wind``: wind, gusts, drag). No I/O.

May import: common.
"""
