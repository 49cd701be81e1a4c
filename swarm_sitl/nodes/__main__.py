"""``python -m swarm_sitl.nodes controller|leader CONFIG ...``: one node process (``entry``)."""

from swarm_sitl.nodes.entry import main

if __name__ == "__main__":
    raise SystemExit(main())
