"""Every parameter of ``px4_quad_x``, declared once: its name, default, range, unit, where the
default comes from and what it does. The model takes its defaults and ranges from here, the
vehicle serves the PX4 ones over MAVLink under these names, and the table in
``docs/vehicles.md`` is ``markdown_table()``'s (``python -m sim_vehicles.plant.px4_params``
prints it; ``tests/test_px4_params.py`` holds the doc to it).

**The release.** The defaults are PX4 v1.15's (``RELEASE``): ``mc_att_control``,
``mc_rate_control`` and the control allocator as v1.15 ships them, on PX4 SIH's quadrotor
(``simulator_sih``'s ``SIH_*``). ``CHANGED_AFTER`` lists what PX4 changed after it, which this
model does not follow.

Groups (``Param.group``): ``airframe`` (the config's ``vehicle.params``, not served: a vehicle's
build is not changed in flight), ``attitude`` and ``rate`` (PX4's, served and set in flight).
The body-rate limits ``MC_*RATE_MAX`` are the vehicle config's ``max_rate_rps`` (rad/s there, deg/s over
MAVLink); their defaults here are what a ``px4_quad_x`` spec without ``max_rate_rps`` gets.
"""

import math
from dataclasses import dataclass

RELEASE = "PX4 v1.15"

#: what PX4 changed after ``RELEASE`` that this model does not follow (name or part: the change)
CHANGED_AFTER = {
    "MC_ROLL_P, MC_PITCH_P": "6.5 -> 4.0 in PX4 main since June 2025",
    "control allocation": (
        "PX4 main (2025) rewrote the sequential desaturation without air mode as "
        "mix(roll_pitch_limit, yaw_limit): the yaw step lowers thrust by at most 0.15 and the "
        "half step is folded into one limited gain"
    ),
}


@dataclass(frozen=True)
class Param:
    """One parameter of the model."""

    name: str
    default: float
    low: float
    high: float
    unit: str  #: "" where it has none
    group: str  #: ``airframe``, ``attitude`` or ``rate``
    source: str  #: where the default (and the range) come from
    meaning: str
    #: the values it may take, where it is a choice (else any value in ``low..high``)
    choices: tuple[float, ...] = ()

    def accepts(self, value: float) -> bool:
        """Whether ``value`` is one this parameter takes."""
        if not (isinstance(value, int | float) and math.isfinite(value) and self.low <= value <= self.high):
            return False
        return not self.choices or value in self.choices


_ATT = "PX4 v1.15 `mc_att_control`"
_RATE = "PX4 v1.15 `mc_rate_control`"
_OURS = "; top: ours (PX4 gives none)"
_LOW = "; bottom: ours (PX4's 0 holds the axis still)"

PARAMS: tuple[Param, ...] = (
    # -- the airframe: PX4 SIH's quadrotor X -------------------------------------------------------
    Param("Q_MAX_NM", 0.1, 1e-6, 10.0, "N m", "airframe", "`SIH_Q_MAX`", "a rotor's largest drag torque"),
    Param("L_ROLL_M", 0.2, 0.01, 5.0, "m", "airframe", "`SIH_L_ROLL`", "rotor distance from the x axis"),
    Param("L_PITCH_M", 0.2, 0.01, 5.0, "m", "airframe", "`SIH_L_PITCH`", "rotor distance from the y axis"),
    Param("T_TAU_S", 0.05, 0.0, 1.0, "s", "airframe", "`SIH_T_TAU`", "the motors' time constant (0: none)"),
    Param(
        "MOTOR_MODEL",
        0,
        0,
        1,
        "",
        "airframe",
        "ours; 0 is SIH's",
        "0: each rotor's thrust lags its actuator (SIH); 1: its speed lags sqrt(actuator) (thrust ~ speed^2)",
        choices=(0, 1),
    ),
    # -- attitude: mc_att_control ----------------------------------------------------------------
    Param("MC_ROLL_P", 6.5, 0.0, 12.0, "1/s", "attitude", _ATT, "roll rate setpoint per rad of error"),
    Param("MC_PITCH_P", 6.5, 0.0, 12.0, "1/s", "attitude", _ATT, "pitch rate setpoint per rad of error"),
    Param("MC_YAW_P", 2.8, 0.0, 5.0, "1/s", "attitude", _ATT, "yaw rate setpoint per rad of error"),
    Param("MC_YAW_WEIGHT", 0.4, 0.0, 1.0, "", "attitude", _ATT, "yaw's share of the attitude error"),
    Param("MC_ROLLRATE_MAX", 220.0, 1.0, 1800.0, "deg/s", "attitude", _ATT + _LOW, "roll rate limit"),
    Param("MC_PITCHRATE_MAX", 220.0, 1.0, 1800.0, "deg/s", "attitude", _ATT + _LOW, "pitch rate limit"),
    Param("MC_YAWRATE_MAX", 200.0, 1.0, 1800.0, "deg/s", "attitude", _ATT + _LOW, "yaw rate limit"),
    # -- rate: mc_rate_control -------------------------------------------------------------------
    Param("MC_ROLLRATE_P", 0.15, 0.01, 0.5, "1/(rad/s)", "rate", _RATE, "roll torque per rad/s of error"),
    Param("MC_PITCHRATE_P", 0.15, 0.01, 0.6, "1/(rad/s)", "rate", _RATE, "pitch torque per rad/s of error"),
    Param("MC_YAWRATE_P", 0.2, 0.0, 0.6, "1/(rad/s)", "rate", _RATE, "yaw torque per rad/s of error"),
    Param("MC_ROLLRATE_I", 0.2, 0.0, 10.0, "1/rad", "rate", _RATE + _OURS, "roll rate integral gain"),
    Param("MC_PITCHRATE_I", 0.2, 0.0, 10.0, "1/rad", "rate", _RATE + _OURS, "pitch rate integral gain"),
    Param("MC_YAWRATE_I", 0.1, 0.0, 10.0, "1/rad", "rate", _RATE + _OURS, "yaw rate integral gain"),
    Param("MC_ROLLRATE_D", 0.003, 0.0, 0.01, "1/(rad/s^2)", "rate", _RATE, "roll torque per rad/s^2"),
    Param(
        "MC_PITCHRATE_D", 0.003, 0.0, 0.1, "1/(rad/s^2)", "rate", _RATE + _OURS, "pitch torque per rad/s^2"
    ),
    Param("MC_YAWRATE_D", 0.0, 0.0, 0.1, "1/(rad/s^2)", "rate", _RATE + _OURS, "yaw torque per rad/s^2"),
    Param("MC_ROLLRATE_K", 1.0, 0.01, 5.0, "", "rate", _RATE, "scales roll P, I and D"),
    Param("MC_PITCHRATE_K", 1.0, 0.01, 5.0, "", "rate", _RATE, "scales pitch P, I and D"),
    Param("MC_YAWRATE_K", 1.0, 0.01, 5.0, "", "rate", _RATE, "scales yaw P, I and D"),
    Param("MC_RR_INT_LIM", 0.3, 0.0, 1.0, "", "rate", _RATE + _OURS, "roll integral limit"),
    Param("MC_PR_INT_LIM", 0.3, 0.0, 1.0, "", "rate", _RATE + _OURS, "pitch integral limit"),
    Param("MC_YR_INT_LIM", 0.3, 0.0, 1.0, "", "rate", _RATE + _OURS, "yaw integral limit"),
    Param("MC_YAW_TQ_CUTOFF", 2.0, 0.0, 10.0, "Hz", "rate", _RATE, "yaw torque low-pass cutoff (0: off)"),
)
BY_NAME = {p.name: p for p in PARAMS}
#: the body-rate limits, roll, pitch, yaw [deg/s]: the vehicle config's ``max_rate_rps``, not a gain
RATE_MAX = ("MC_ROLLRATE_MAX", "MC_PITCHRATE_MAX", "MC_YAWRATE_MAX")
AIRFRAME = {p.name: float(p.default) for p in PARAMS if p.group == "airframe"}
#: the gains the controllers' kernels take (``px4_control.GAINS``'s order), with their defaults
GAINS = {p.name: float(p.default) for p in PARAMS if p.group != "airframe" and p.name not in RATE_MAX}
#: ``max_rate_rps`` of a ``px4_quad_x`` spec that gives none [rad/s]: PX4's MC_*RATE_MAX
DEFAULT_MAX_RATE_RPS = tuple(math.radians(BY_NAME[n].default) for n in RATE_MAX)


def _number(x: float) -> str:
    return f"{x:g}"


def markdown_table() -> str:
    """The parameter table of ``docs/vehicles.md``, from ``PARAMS``."""
    lines = [
        "| parameter | default | range | unit | where | what it does |",
        "|---|---|---|---|---|---|",
    ]
    for p in PARAMS:
        rng = (
            ", ".join(_number(c) for c in p.choices) if p.choices else f"{_number(p.low)}..{_number(p.high)}"
        )
        lines.append(f"| `{p.name}` | {_number(p.default)} | {rng} | {p.unit} | {p.source} | {p.meaning} |")
    return "\n".join(lines) + "\n"


def changed_after_lines() -> str:
    """What PX4 changed after ``RELEASE`` (``CHANGED_AFTER``), as a markdown list."""
    return "".join(f"- {what}: {change}\n" for what, change in CHANGED_AFTER.items())


if __name__ == "__main__":
    print(markdown_table(), end="")
