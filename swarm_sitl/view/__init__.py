"""The swarm in a browser: a live run's page (``run --view``) and a finished run's (``view``);
and in Foxglove, live (``run --foxglove``).

- ``layout``: the communication graph laid out by hops from the leader, no label on another's;
- ``frames``: the page's frame document declared once (a frame's fields by name, frames as
  columns), which the replay, the live feed, the Foxglove stream and the page follow;
- ``replay``: a run directory as the page's document (frames of the formation, its errors, each
  edge's age, each follower's state; the plan's windows, the events), and its source for the
  server;
- ``live``: a running swarm's document, fed by its supervisor with what it already reads;
- ``server``: the page and its assets from the installed package, and the document, over HTTP on
  loopback, one thread per request: a browser never holds up a run;
- ``foxglove_live``: the live feed's frames and events to Foxglove over its WebSocket protocol
  (``run --foxglove``), on the MCAP export's topics.

May import: sim_vehicles.common, laws, bus, faults, config, rundir.
"""
