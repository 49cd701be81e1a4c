"""Hypothesis strategies shared by the tests."""

import numpy as np
from hypothesis import strategies as st

finite = st.floats(-10.0, 10.0, allow_nan=False, allow_infinity=False)
vec3 = st.tuples(finite, finite, finite).map(np.array)


@st.composite
def unit_quaternions(draw):
    q = np.array([draw(st.floats(-1, 1)) for _ in range(4)])
    n = np.linalg.norm(q)
    if n < 1e-3:
        q = np.array([1.0, 0.0, 0.0, 0.0])
        n = 1.0
    return q / n
