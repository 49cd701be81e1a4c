"""What both packages share, pure and small: how kernels are compiled (``jit``), quaternion
algebra (``quaternion``), the layout of a vehicle's state vector (``state``) and the attitude
command a controller sends and a vehicle holds (``command``), how a plug-in named by an
entry (``"my_file.py:Class"``) is loaded and its declared parameters read (``entry``), and how a
plug-in is held to its contract, a ``Protocol`` (``contract``).

May import: nothing of ours.
"""
