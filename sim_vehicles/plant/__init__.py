"""The simulated aircraft, pure: its parameters (``params``), the 6-DOF rigid body
(``rigid_body``), the paper's torque law (``torque_law``), the attitude loop that holds a command
(``autopilot``) and what it flies when its setpoints stop (``failsafe``). No I/O.

May import: common.
"""
