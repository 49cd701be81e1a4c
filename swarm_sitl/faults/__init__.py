"""Faults as a test input: the plan (what fails x how x when) and the wrappers that carry it out.

- ``plan``: the ``faults:`` section of a config, validated at load, and each message's fate, a
  pure function of the plan's seed and the message (``fate``): the same plan, the same run;
- the link models a plan entry may name, each a pure function of the run's inputs and a class
  of one contract (``link_model``: also the plug-in point for a model of the user's, ``model:
  {entry, params}``, ``docs/links.md``), registered in ``link_models``: ``loss`` (drop, loss),
  ``delays`` (delay, stall, reorder), ``copies`` (duplicate, corrupt), ``bursts``
  (Gilbert-Elliott), ``radio_range`` (path loss with distance, retries), ``bandwidth`` (a node's
  radio and its queue), with ``draws``, the seeded draws they make;
- ``edges``: the plan on a node's in-edges, a wrapper of its bus (``FaultyBus``), its stage on
  each estimate (``in_edges``), and in lockstep the fates a block of ticks at a time
  (``fate_table``);
- ``mavlink``: the plan on a vehicle's MAVLink link, a wrapper of the controller's datagrams;
- ``counts``: what those wrappers count per edge and per link, in memory or in a file that
  outlives a killed process;
- ``processes``: killing, freezing and restarting processes, through a small protocol of the
  supervisor's.

Nothing in the loops or the laws knows about faults: they are wrappers of injected interfaces.

May import: sim_vehicles.common, sim_vehicles.runtime, laws, bus.
"""
