"""Running a swarm: in one process (``sim``; a fault plan in it: ``sim_plan``), or as processes
that are started, supervised and torn down all or nothing (``run``: the whole run;
``supervisor``: the children; ``observers``: what the supervisor's loop watches and feeds,
declared once; ``ends``: a process that ended early or stopped ticking, named, and a run's exit
rules;
``vehicles``: the simulated vehicles; ``hub``: the supervisor's zenoh session and view of the
bus; ``fork_server``: children forked from one warmed-up process; ``children``: a child's command
line and environment; ``router_watch``: a client-mode run's zenoh router, lost and back;
``first_compile``: every compiled kernel of a fresh install, once, on two processes;
``warm_commands``: ``swarm-sitl`` commands (a campaign's runs) forked from one warm server;
``vehicle_relay``: a plan's MAVLink faults at a vehicle's port, for a controller the bench does
not run; ``ros2_face``: the run on ROS 2 topics, through the supervisor's session).

May import: sim_vehicles, laws, bus, faults, config, rundir, link, nodes, view, ros2.
"""
