"""A vehicle's physical and attitude-loop parameters (``plant.params``): accepted exactly when
each is inside its bound, over values drawn on, just beside and far from every bound; a refusal
is one error that names the field and the value it was given."""

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim_vehicles.plant.params import AttitudeGains, VehicleParamError, VehicleParams

pytestmark = pytest.mark.unit

#: values on every bound these parameters have (0, 1 and infinity), one float either side, and
#: ordinary values: a bound off by one comparison or by one unit is met on its edge
EDGES = [0.0, 1.0, math.inf]
NEAR = [v for e in EDGES for v in (e, math.nextafter(e, -math.inf), math.nextafter(e, math.inf))]
values = st.one_of(st.sampled_from([*NEAR, -1.0, 0.5, 2.0, math.nan]), st.floats(-5.0, 60.0))
triples = st.one_of(st.tuples(values, values, values), st.lists(values, min_size=0, max_size=5).map(tuple))


def _refusal(mass, inertia, thrust_rel, g, rates, drag):
    """The field the bounds refuse first (None: accepted), stated from the physics: a positive
    mass; three positive principal inertias; more thrust than the weight m g (or it cannot hover);
    three body-rate limits that are positive and finite; a drag coefficient that is not negative
    and finite."""
    weight = mass * g
    if thrust_rel in ("edge", "above"):  # the weight itself, or the next float above it
        thrust = weight if thrust_rel == "edge" else math.nextafter(weight, math.inf)
    else:
        thrust = weight * thrust_rel
    if math.isnan(mass) or mass <= 0:
        return "mass_kg", thrust
    if len(inertia) != 3 or any(math.isnan(j) or j <= 0 for j in inertia):
        return "inertia_kgm2", thrust
    if math.isnan(thrust) or math.isnan(weight) or thrust <= weight:
        return "max_thrust_N", thrust
    if len(rates) != 3 or any(not (math.isfinite(w) and w > 0) for w in rates):
        return "max_rate_rps", thrust
    if not (math.isfinite(drag) and drag >= 0):
        return "drag_Ns2pm2", thrust
    return None, thrust


def _check(mass, inertia, thrust_rel, g, rates, drag) -> None:
    """``VehicleParams`` accepts these exactly when ``_refusal`` finds none refused, and a refusal
    is one line that starts with the field and holds the value given."""
    field, thrust = _refusal(mass, inertia, thrust_rel, g, rates, drag)
    if field is None:
        p = VehicleParams(mass, inertia, thrust, g, rates, drag)
        assert p.hover_thrust_N == mass * g and list(p.inertia) == list(inertia)
        return
    with pytest.raises(VehicleParamError) as e:
        VehicleParams(mass, inertia, thrust, g, rates, drag)
    line = str(e.value)
    assert line.startswith(field) and "\n" not in line, line
    given_value = {"mass_kg": mass, "inertia_kgm2": inertia, "max_thrust_N": thrust}.get(field)
    given_value = {"max_rate_rps": rates, "drag_Ns2pm2": drag}.get(field, given_value)
    assert str(given_value) in line, line  # the value it was given, as the user wrote it
    if field == "max_thrust_N":  # and the weight it must exceed, in newtons
        assert f"({mass * g:.3f} N)" in line, line


#: the largest thrust as a multiple of the weight, or the weight exactly, or one float above it
thrust_rels = st.one_of(st.sampled_from(["edge", "above", 1.0000001, 0.999999, 0.05]), st.floats(-1.0, 5.0))
positive = st.floats(1e-3, 50.0)
#: each field inside its bounds, and each from anywhere (``values``)
VALID = {
    "mass": positive,
    "inertia": st.tuples(positive, positive, positive),
    "thrust_rel": st.floats(1.01, 5.0),
    "rates": st.tuples(positive, positive, positive),
    "drag": st.floats(0.0, 5.0),
}
ANY = {"mass": values, "inertia": triples, "thrust_rel": thrust_rels, "rates": triples, "drag": values}


@settings(max_examples=500, deadline=None, derandomize=True)
@given(data=st.data(), g=st.sampled_from([9.81, 1.62, 0.5, 3.0]))
def test_the_parameters_are_accepted_exactly_inside_their_bounds(data, g):
    """All fields from anywhere (the first refused is named), or all inside their bounds but one
    from anywhere (so each bound is met on its own edge)."""
    odd = data.draw(st.sampled_from([*VALID, "all"]), label="drawn from anywhere")
    f = {k: data.draw(ANY[k] if odd in (k, "all") else VALID[k], label=k) for k in VALID}
    mass, inertia, thrust_rel, rates, drag = f["mass"], f["inertia"], f["thrust_rel"], f["rates"], f["drag"]
    _check(mass, inertia, thrust_rel, g, rates, drag)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(l_q=values, k_q=values)
def test_the_torque_laws_gains_are_accepted_exactly_when_both_are_positive(l_q, k_q):
    if l_q > 0 and k_q > 0:  # (False for a NaN)
        assert AttitudeGains(l_q, k_q).l_q == l_q
        return
    with pytest.raises(VehicleParamError) as e:
        AttitudeGains(l_q, k_q)
    line = str(e.value)
    assert all(s in line for s in ("l_q", "k_q", str(l_q), str(k_q))) and "\n" not in line, line


BASE = {"mass": 0.85, "inertia": (0.05, 0.05, 0.09), "thrust_rel": 3.0, "rates": (3.0, 3.0, 2.0), "drag": 0.1}
ON_EDGES = [*NEAR, -1.0, math.nan]
#: every field on every edge alone, the others inside their bounds (each tuple's first or last)
EDGE_CASES = (
    [(k, v) for k in ("mass", "drag") for v in ON_EDGES]
    + [(k, t) for k in ("inertia", "rates") for v in ON_EDGES for t in ((v, 1.0, 2.0), (2.0, 1.0, v))]
    + [(k, t) for k in ("inertia", "rates") for t in ((), (1.0, 1.0), (1.0,) * 4)]
    + [("thrust_rel", r) for r in ("edge", "above", 0.9999999, 0.0, -1.0, math.nan)]
)


@pytest.mark.parametrize(("field", "value"), EDGE_CASES, ids=lambda v: repr(v))
def test_each_bound_is_met_on_its_own_edge(field, value):
    f = {**BASE, field: value}
    _check(f["mass"], f["inertia"], f["thrust_rel"], 9.81, f["rates"], f["drag"])
