"""``swarm-sitl check`` for a law other than the paper's: what the bench can check before a run.

Theorem 1's conditions are the paper's law's (``laws.gain_conditions``); for another law the
bench checks what every law needs: a graph in which the leader reaches every follower (each
follower's hops from it), rates (control and attitude periods, how many periods a message may
age before it leaves the inbox), the traffic the law's message makes, and that the law builds
for every follower and steps once on still inputs with an output that meets the contract.
"""

from swarm_sitl.bus.codec import message_size
from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.laws.contract import REFERENCE_LENGTH
from swarm_sitl.nodes.assembly import first_tick, reported_vehicle_params
from swarm_sitl.nodes.law_host import LawError


def hops_from_leader(cfg: SwarmConfig) -> dict[int, int]:
    """Each follower's fewest hops from node 0 on the graph (config validation has already
    refused a graph where the leader does not reach every follower)."""
    hops = cfg.build_graph().hops_from(0)
    return {i: hops[i] for i in sorted(hops) if i > 0}


def first_ticks(cfg: SwarmConfig) -> list[str]:
    """Each follower's law built and stepped once (``assembly.first_tick``): one line per
    follower, ``ok`` or the law's one-line error."""
    mass, max_thrust = reported_vehicle_params(cfg)
    lines = []
    for f in cfg.followers:
        try:
            step = first_tick(cfg, f.id, mass, max_thrust)
            lines.append(f"  follower {f.id}: builds, first tick ok (thrust {step.command.thrust_N:.3g} N)")
        except LawError as e:
            lines.append(f"  follower {f.id}: FAILS: {e}")
    return lines


def render_law_check(cfg: SwarmConfig, name: str) -> tuple[str, bool]:
    """The report, and whether every check passed."""
    cls = cfg.law_class()
    graph = cfg.build_graph()
    hops = hops_from_leader(cfg)
    n_edges = len(cfg.graph.edges)
    from_leader = len(graph.out_neighbours(0))
    per_msg = message_size(cls.message_length)
    bus_Bps = (
        from_leader * message_size(REFERENCE_LENGTH) + (n_edges - from_leader) * per_msg
    ) * cfg.rates.control_hz
    stale_periods = cfg.estimator.staleness_s / cfg.control_dt_s
    ticks = first_ticks(cfg)
    ok = not any("FAILS" in line for line in ticks)
    lines = [
        f"config {name}: law {cfg.law.entry}",
        "  Theorem 1's gain conditions belong to the paper's law (swarm_sitl.laws.zou_meng:ZouMengLaw);",
        "  they are not checked for this one. What is checked:",
        "  graph: the leader reaches every follower (a spanning tree rooted at node 0); hops from it: "
        + ", ".join(f"{i}: {h}" for i, h in hops.items()),
        f"  rates: control {cfg.rates.control_hz:g} Hz ({cfg.control_dt_s * 1000:g} ms), attitude loop "
        f"{cfg.rates.attitude_hz:g} Hz ({cfg.rates.attitude_steps_per_control} steps per control period); "
        f"a message leaves the inbox after estimator.staleness_s = {cfg.estimator.staleness_s:g} s "
        f"({stale_periods:g} periods)",
        f"  message: {cls.message_length} float64 ({per_msg} bytes on the bus), on {n_edges} edges: "
        f"{bus_Bps / 1000:.1f} kB/s in all; records {dict(cls.record_fields)}",
        f"  params: {cfg.law_params()!r}",
        *ticks,
        "",
        "ok: the law builds and ticks for every follower"
        if ok
        else "FAILS: the law does not tick for every follower (above)",
    ]
    return "\n".join(lines), ok
