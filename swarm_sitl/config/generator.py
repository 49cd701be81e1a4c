"""``swarm-sitl new``: write a commented config for a generated swarm.

A swarm is N followers on a directed graph (``ring``, ``tree``, ``layered``, ``random``), in a
formation (``circle``, ``grid``, ``line``), behind a leader flying a ``helix``, ``figure_eight`` or
``line``. Gains start from the paper's; where Theorem 1's conditions (``swarm-sitl check``) fail on
the graph, the check's suggestion is taken when it satisfies them all, and the file's comments say
which conditions fail otherwise. The text is parsed with the config schema before it is returned,
so what is written always loads.
"""

import json
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import yaml

from swarm_sitl.config.law_entry import absolute_entry
from swarm_sitl.config.load import ConfigError, parse_config
from swarm_sitl.config.schema import PAPER_LAW, LeaderSection, SwarmConfig
from swarm_sitl.laws.gain_conditions import check_gains

GRAPHS = ("ring", "tree", "layered", "random")
FORMATIONS = ("circle", "grid", "line")
TRAJECTORIES = ("helix", "figure_eight", "line")
SPACING_M = 4.0  #: between neighbouring places of a formation [m]
INITIAL_SPREAD_M = 2.0  #: initial positions are the formation's places +- this on each axis [m]
PAPER_GAINS = dict(k_gamma=0.5, k_p=8.0, k_v=8.0, l_a=12.0, k_a=4.0, l_p=4.0, l_v=4.0, k_eta=4.0)
#: the suggestion of ``check`` is taken only up to this k_p = k_v. The conditions are sufficient,
#: and the gains they ask grow fast with n; in sampled time the sgn term's chattering grows with
#: them. Measured (`sim`, 20 s, helix, grid): layered16 with the suggestion (k_p 94, k_a 152)
#: 4.3 mm against 0.6 mm with the paper's gains; tree32 (k_p 632, k_a 542) 21 mm against 0.68 mm;
#: layered32's (k_p 3854) is past RK4's stability at the 1 ms estimator step.
MAX_SUGGESTED_K = 200.0

TRAJECTORY_YAML = {
    "helix": "{type: helix, radius_m: 5.0, angular_rate_radps: 0.2, climb_rate_mps: 1.0}",
    "figure_eight": "{type: figure_eight, amplitude_x_m: 8.0, amplitude_y_m: 4.0, angular_rate_radps: 0.1}",
    "line": "{type: line, start_m: [0.0, 0.0, 0.0], velocity_mps: [1.0, 0.5, 0.2]}",
}
TRAJECTORY_TEXT = {
    "helix": "the paper's helix: radius 5 m, 0.2 rad/s, climbing 1 m/s",
    "figure_eight": "a figure eight 16 m x 8 m, one loop in 63 s",
    "line": "a straight line at 1.1 m/s",
}


class GeneratorError(ValueError):
    """A request ``swarm-sitl new`` cannot build; the message is one line."""


# -- graphs: (src, dst) edges, node 0 the leader -------------------------------------------------
def ring_edges(n: int, rng: np.random.Generator) -> list[tuple[int, int]]:
    """Leader -> 1 -> 2 -> ... -> n -> 1: a directed cycle behind one leader link."""
    return [(0, 1)] + [(i, i + 1) for i in range(1, n)] + ([(n, 1)] if n > 1 else [])


def tree_edges(n: int, rng: np.random.Generator) -> list[tuple[int, int]]:
    """A binary tree rooted at the leader: node j feeds 2j + 1 and 2j + 2."""
    return [((i - 1) // 2, i) for i in range(1, n + 1)]


def layer_width(n: int) -> int:
    return max(1, math.ceil(math.sqrt(n)))


def layered_edges(n: int, rng: np.random.Generator) -> list[tuple[int, int]]:
    """Rows of ``w = ceil(sqrt(n))``: the leader feeds the first row; follower j of a later row
    hears j - w (in front) and, off the first column, j - w - 1 (diagonally in front)."""
    w = layer_width(n)
    edges = [(0, j) for j in range(1, min(w, n) + 1)]
    for j in range(w + 1, n + 1):
        edges.append((j - w, j))
        if (j - 1) % w:
            edges.append((j - w - 1, j))
    return edges


def random_edges(n: int, rng: np.random.Generator) -> list[tuple[int, int]]:
    """A random spanning tree from the leader (follower i hears one of 0..i-1), plus about n/2
    random edges between followers, which may close cycles."""
    edges = [(int(rng.integers(0, i)), i) for i in range(1, n + 1)]
    taken = set(edges)
    for _ in range(n // 2):
        s, d = (int(x) for x in rng.integers(1, n + 1, size=2))
        if s != d and (s, d) not in taken:
            edges.append((s, d))
            taken.add((s, d))
    return edges


GRAPH_BUILDERS: dict[str, Callable[[int, np.random.Generator], list[tuple[int, int]]]] = {
    "ring": ring_edges,
    "tree": tree_edges,
    "layered": layered_edges,
    "random": random_edges,
}
GRAPH_TEXT = {
    "ring": "a directed ring behind one leader link: 0 -> 1 -> 2 -> ... -> n -> 1",
    "tree": "a binary tree rooted at the leader: node j feeds 2j+1 and 2j+2",
    "layered": "rows of ceil(sqrt(n)); the leader feeds the first row, each follower hears the one "
    "in front and the one diagonally in front",
    "random": "a random spanning tree from the leader plus about n/2 random edges between followers",
}


# -- formations: offsets delta_i ------------------------------------------------------------------
def formation_offsets(kind: str, n: int) -> np.ndarray:
    """``(n, 3)`` offsets in the horizontal plane, centred on the leader, ``SPACING_M`` apart."""
    if kind == "circle":
        radius = 0.0 if n == 1 else SPACING_M / (2 * math.sin(math.pi / n))  # neighbours SPACING_M apart
        a = 2 * math.pi * np.arange(n) / n
        return np.stack([radius * np.cos(a), radius * np.sin(a), np.zeros(n)], axis=1)
    if kind == "grid":
        w = layer_width(n)
        col, row = np.arange(n) % w, np.arange(n) // w
        rows = math.ceil(n / w)
        return np.stack(
            [SPACING_M * (col - (w - 1) / 2), SPACING_M * (row - (rows - 1) / 2), np.zeros(n)], axis=1
        )
    if kind == "line":
        x = SPACING_M * (np.arange(n) - (n - 1) / 2)
        return np.stack([x, np.zeros(n), np.zeros(n)], axis=1)
    raise GeneratorError(f"--formation must be one of {', '.join(FORMATIONS)}, got {kind!r}")


def _num(x: float) -> str:
    """``x`` to six significant digits as YAML reads a number back: PyYAML (YAML 1.1) takes
    ``1e-05`` for a string, so an exponent's mantissa gets its point (``1.0e-05``)."""
    text = f"{x:.6g}"
    mantissa, e, exponent = text.partition("e")
    return f"{mantissa}.0e{exponent}" if e and "." not in mantissa else text


def _vec(v: np.ndarray) -> str:
    return "[" + ", ".join(_num(float(x)) for x in v) + "]"


def _choose_gains(cfg: SwarmConfig) -> tuple[dict[str, float], list[str]]:
    """The paper's gains, or ``check``'s suggestion when they fail and it satisfies everything;
    and the comment lines that say which."""
    graph, traj = cfg.build_graph(), cfg.trajectory()
    horizon = max(cfg.duration_s, 200.0)
    report = check_gains(graph, cfg.gain_dict(), traj, cfg.gravity_mps2, horizon)
    if report.all_hold:
        return dict(PAPER_GAINS), [
            "the paper's gains: every condition of `swarm-sitl check` holds on this graph"
        ]
    failing = [c.name for c in report.conditions if not c.holds]
    suggested = {**PAPER_GAINS, **report.suggestion}
    ok = check_gains(graph, suggested, traj, cfg.gravity_mps2, horizon).all_hold
    if ok and max(suggested["k_p"], suggested["k_v"]) <= MAX_SUGGESTED_K:
        return suggested, [
            "the paper's gains fail on this graph: " + "; ".join(failing),
            "these are `swarm-sitl check`'s suggestion, with which every condition holds",
        ]
    why = (
        f"the gains that satisfy them need k_p = k_v = {suggested['k_p']:.4g}, k_a = {suggested['k_a']:.4g}: "
        f"past {MAX_SUGGESTED_K:g} the sampled sgn term's chattering costs more than the guarantee gives"
        if ok
        else "no gains were found that satisfy them"
    )
    return dict(PAPER_GAINS), [
        "the paper's gains; Theorem 1's sufficient conditions FAIL on this graph (it may still converge):",
        *("  " + name for name in failing),
        f"({why})",
    ]


def _params(params: dict[str, float] | None) -> str:
    """A flow mapping of a model's parameters (``{}``: none)."""
    return "{" + ", ".join(f"{k}: {_num(float(v))}" for k, v in (params or {}).items()) + "}"


def generate(
    followers: int,
    graph: str,
    formation: str,
    trajectory: str,
    seed: int = 0,
    duration_s: float = 60.0,
    law: str | None = None,
    law_base: Path | None = None,
    vehicle: str | None = None,
    vehicle_params: dict[str, float] | None = None,
) -> str:
    """The YAML text of a generated swarm (parsed with the schema before it is returned). ``law``:
    the followers' law entry as the file will hold it (a file entry relative to ``law_base``, the
    directory the config is written to); default the paper's. ``vehicle``: the vehicle model, a
    registered one's name or an entry held as ``law`` is; default the paper's vehicle;
    ``vehicle_params``: its parameters (``vehicle.params``), held to the model as any config's are."""
    if not 1 <= followers <= 254:
        raise GeneratorError(f"--followers must be 1..254 (MAVLink system ids), got {followers}")
    if not 0 < duration_s < math.inf:
        raise GeneratorError(f"--duration must be a number of seconds > 0, got {duration_s}")
    if graph not in GRAPH_BUILDERS:
        raise GeneratorError(f"--graph must be one of {', '.join(GRAPHS)}, got {graph!r}")
    if trajectory not in TRAJECTORY_YAML:
        raise GeneratorError(f"--trajectory must be one of {', '.join(TRAJECTORIES)}, got {trajectory!r}")
    rng = np.random.default_rng(seed)
    edges = GRAPH_BUILDERS[graph](followers, rng)
    offsets = formation_offsets(formation, followers)
    name = f"{graph}{followers}-{formation}-{trajectory}".replace("_", "-")

    # the leader's start, for the initial positions: the trajectory's own p_r(0)
    leader = LeaderSection.model_validate({"trajectory": yaml.safe_load(TRAJECTORY_YAML[trajectory])})
    p0 = np.asarray(leader.trajectory.build().derivatives(0.0)[0], dtype=float)
    spread = np.random.default_rng([seed, 1]).uniform(-INITIAL_SPREAD_M, INITIAL_SPREAD_M, offsets.shape)
    start = offsets + p0 + spread

    def text(gains: dict[str, float], gain_notes: list[str]) -> str:
        lines = [
            f"# Generated by: swarm-sitl new --followers {followers} --graph {graph} "
            f"--formation {formation} --trajectory {trajectory} --seed {seed}",
            f"# {followers} followers; graph: {GRAPH_TEXT[graph]};",
            f"# formation: {formation}, places {SPACING_M:g} m apart; leader: {TRAJECTORY_TEXT[trajectory]}.",
            f"# Initial positions: each place +- {INITIAL_SPREAD_M:g} m (seed {seed}). Edit freely; "
            "`swarm-sitl check` re-reads the conditions.",
            f"name: {name}",
            f"duration_s: {_num(duration_s)}",
            "gravity_mps2: 9.81",
            "",
            "rates:",
            "  control_hz: 100          # estimator exchange and position loop (SET_ATTITUDE_TARGET rate)",
            "  attitude_hz: 1000        # vehicle attitude loop and plant integration",
            "  estimator_substeps: 10   # RK4 steps of the estimator per control period (1 ms)",
            "",
            "leader:",
            f"  trajectory: {TRAJECTORY_YAML[trajectory]}",
            "",
            "graph:",
            f"  # {len(edges)} edges [src, dst]: dst hears src (0 is the leader)",
            "  edges:",
            *(f"    - [{s}, {d}]" for s, d in edges),
            "",
            "vehicle:",
            "  mass_kg: 0.85",
            "  inertia_kgm2: [0.04856, 0.04856, 0.08801]",
            "  max_thrust_N: 25.0       # above the law's bound m (g + 2 sqrt3 k_eta + sqrt3 k_gamma)",
            "  setpoint_timeout_s: 0.5",
            "  l_q: 16.0                # the attitude loop (the paper's torque law)",
            "  k_q: 16.0",
            *(
                [
                    f"  model: {json.dumps(vehicle)}  # docs/vehicles.md",
                    f"  params: {_params(vehicle_params)}",
                ]
                if vehicle
                else []
            ),
            "",
            "followers:",
            *(
                f"  - {{id: {i + 1}, offset_m: {_vec(offsets[i])}, initial_position_m: {_vec(start[i])}}}"
                for i in range(followers)
            ),
            "",
            "gains:",
            *(f"  # {note}" for note in gain_notes),
            *(f"  {k}: {_num(float(v))}" for k, v in gains.items()),
            "",
            "estimator:",
            "  bracket: sliding_surface     # the form Theorem 1 covers",
            "  sign_boundary_layer: 0.0     # 0 = the paper's sgn()",
            "  neighbour_hold: extrapolate",
            "",
        ]
        if law is not None and law != PAPER_LAW:
            lines += [
                "# the followers' law (docs/laws.md); the gains above are the paper's law's, unused with it",
                "law:",
                f"  entry: {json.dumps(law)}",
                "  params: {}",
                "",
            ]
        return "\n".join(lines)

    def parsed(text_: str) -> SwarmConfig:
        data = yaml.safe_load(text_)
        if "law" in data:  # validated as load_config will: a file entry found from the config's directory
            data["law"]["entry"] = absolute_entry(data["law"]["entry"], law_base or Path.cwd())
        if ":" in data["vehicle"].get("model", ""):
            data["vehicle"]["model"] = absolute_entry(data["vehicle"]["model"], law_base or Path.cwd())
        try:
            return parse_config(data, "generated config")
        except ConfigError as e:
            raise GeneratorError(str(e).removeprefix("generated config: ")) from None

    draft = parsed(text(PAPER_GAINS, []))
    gains, notes = _choose_gains(draft)
    out = text(gains, notes)
    parsed(out)
    return out
