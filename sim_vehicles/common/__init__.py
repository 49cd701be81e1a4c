"""What both packages share, pure and small: how kernels are compiled (``jit``), quaternion
algebra (``quaternion``), the layout of a vehicle's state vector (``state``) and the attitude
command a controller sends and a vehicle holds (``command``).

May import: nothing of ours.
"""
