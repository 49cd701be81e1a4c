"""What both packages share, pure and small: how kernels are compiled (``jit``) and quaternion
algebra (``quaternion``).

May import: nothing of ours.
"""
