"""Requirements as signal temporal logic: what a run must do, each with a robustness in its
signal's unit (positive: it holds, and by how much).

- ``formula``: the logic's grammar, parsed into a tree (``always``, ``eventually`` over intervals,
  ``and``, ``or``, ``not``, ``implies``, comparisons of a signal with a number);
- ``robustness``: a formula's robustness over sampled signals, as rtamt's discrete-time monitor
  gives it;
- ``requirement``: a config's ``spec:`` entry (a name, what it ranges over, a formula), checked
  when the config is read.

What the signals are for a run, and the verdicts in its summary: ``rundir.requirements``.

May import: nothing of ours.
"""
