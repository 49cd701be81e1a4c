"""Hypothesis strategies shared by the tests."""

import os

import numpy as np
import pytest
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

#: inputs per fuzz test: a few hundred in the default run; the closing figures of the hostile-input
#: issue used ``SWARM_SITL_FUZZ_EXAMPLES=100000 python -m pytest tests -k fuzz``
EXAMPLES = int(os.environ.get("SWARM_SITL_FUZZ_EXAMPLES", "300"))
#: pytest-timeout for a fuzz test: the suite's 300 s, or more for a long run (about 5 ms an input)
FUZZ_TIMEOUT = pytest.mark.timeout(max(300, int(EXAMPLES * 0.005 * 4)))
FUZZ = settings(
    max_examples=EXAMPLES,
    deadline=None,
    derandomize=EXAMPLES <= 1000,  # the default run is the same every time
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)

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


def in_range(low: float, high: float, *also: float) -> st.SearchStrategy[float]:
    """A value in ``low..high``: its two ends (and ``also``, e.g. a default) drawn as often as the
    rest, as an end is where a division or a weight of zero waits."""
    return st.one_of(st.sampled_from([low, high, *also]), st.floats(low, high))
