"""The subcommands of ``swarm-sitl`` (``cli``), each a function of its parsed arguments with the
parser that defines them: ``runs`` (sim, run, vehicles, controllers), ``tools`` (check, new,
router, plot, export; ``law_check``: check for a law other than the paper's), ``bench``,
``campaign`` (sweep), ``falsify``, ``view`` (view, and run's live page); ``common`` has what they
share; ``run_options``: run's options that name followers, checked; ``run_progress``: run's progress bar.
``controller`` and ``leader`` are the node processes' own (``nodes.arguments``).

May import: sim_vehicles, laws, bus, faults, config, rundir, link, nodes, running, bench, campaigns,
falsify, view, ros2.
"""
