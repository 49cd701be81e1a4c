"""What a long-running process of the bench needs besides its work: when each UDP datagram
arrived (``udp_arrival``), its life as a supervised child (``lifeline``), and files that a crash
cannot make unreadable (``row_log``, ``event_log``, and a counter a restarted process takes up:
``counter_file``), a secret written for its owner alone (``secret_file``). No numerics.

May import: nothing of ours.
"""
