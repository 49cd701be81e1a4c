"""The simulated aircraft, pure: its parameters (``params``), the 6-DOF rigid body
(``rigid_body``), the paper's torque law (``torque_law``), the attitude loop that holds a command
(``autopilot``), what it flies when its setpoints stop (``failsafe``), what it reports of its
state (``sensors``: latency and noise) and the air it flies in (``wind``: wind, gusts, drag). No I/O.

A rotor-level quadrotor beside the paper's vehicle: four rotors in X and their motors
(``rotors``), PX4's control allocation (``px4_allocation``), PX4's attitude and rate controllers
(``px4_control``), their parameters declared once (``px4_params``), all as one model
(``quad_x``). ``contract`` says what any vehicle model is to the endpoint and to ``sim``.

May import: common.
"""
