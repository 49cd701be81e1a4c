"""Reading a config: a YAML file (or a mapping) into a validated ``SwarmConfig``.

``load_config(path)`` returns a frozen ``SwarmConfig`` or raises ``ConfigError`` whose message is
one line naming the offending key (``schema`` says what a config is). A law given by file
(``law.entry: "my_law.py:MyLaw"``), and so a vehicle model (``vehicle.model:
"my_vehicle.py:MyVehicle"``), is found relative to the config file; the loaded config holds
its absolute path, so the run directory's copy of it names the same file. ``with_faults`` puts a fault
plan file in place of a config's own plan, validated against it.
"""

import math
from pathlib import Path
from typing import Any

import yaml
from pydantic import ValidationError

from swarm_sitl.config.law_entry import LawEntryError, absolute_entry
from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.faults.link_model import RECORDED

#: libyaml's safe loader where PyYAML was built with it (7x faster: every process of a run reads
#: the run's config at start), else the pure-Python one; both accept exactly safe YAML
_YAML_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class ConfigError(ValueError):
    """A config file is unreadable or invalid; the message is one line naming the problem."""


def _describe(err: ValidationError) -> str:
    e = err.errors()[0]
    loc = ".".join(
        str(p) for p in e["loc"] if not (isinstance(p, str) and p in {"helix", "figure_eight", "line"})
    )
    kind = e["type"]
    if kind == "missing":
        return f"{loc}: missing key"
    if kind == "extra_forbidden":
        return f"{loc}: unknown key"
    msg = e["msg"].removeprefix("Value error, ")
    where = f"{loc}: " if loc else ""
    got = e.get("input")
    shown = "" if kind.startswith("value_error") or isinstance(got, dict | list) else f" (got {got!r})"
    return f"{where}{msg}{shown}"


def parse_config(data: object, source: str = "config", recorded: bool = False) -> SwarmConfig:
    """``data`` validated; ``recorded``: a run's record, whose plug-ins are named, not imported
    (``load_recorded``)."""
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: expected a mapping of keys at the top level")
    try:
        return SwarmConfig.model_validate(data, context=RECORDED if recorded else None)
    except ValidationError as err:
        raise ConfigError(f"{source}: {_describe(err)}") from None


def _read_text(p: Path) -> str:
    try:
        return p.read_text()
    except OSError as e:
        raise ConfigError(f"{p}: cannot read ({e.strerror})") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{p}: not a text file") from None


def _read_yaml(p: Path, text: str | None = None) -> object:
    text = _read_text(p) if text is None else text
    try:
        return yaml.load(text, Loader=_YAML_LOADER)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        raise ConfigError(f"{p}: not valid YAML{where}") from None


#: the last config loaded, by (path, text): a process forked from one that loaded the run's config
#: (``fork_server``) gets it without parsing and validating it again (12-15 ms of CPU for a
#: 64-follower config, in each of 129 processes)
_LAST: dict[tuple[str, str, bool], SwarmConfig] = {}


def load_recorded(run_dir: str | Path) -> SwarmConfig:
    """The ``config.yaml`` of run directory ``run_dir``, read as what was flown: checked as any
    config is, but no plug-in it names (a law, a vehicle model, a link model) is imported, so a
    run directory reads on a machine without them (``plot``, ``export``, ``merge``). Such a config
    must not be flown: its law's interface is ``rundir.plugins.recorded_law``."""
    return load_config(Path(run_dir) / "config.yaml", recorded=True)


def load_config(path: str | Path, recorded: bool = False) -> SwarmConfig:
    p = Path(path)
    text = _read_text(p)
    key = (str(p), text, recorded)
    cfg = _LAST.get(key)
    if cfg is None:
        data = _read_yaml(p, text)
        law = data.get("law") if isinstance(data, dict) else None
        if isinstance(law, dict) and isinstance(law.get("entry"), str):
            try:
                entry = absolute_entry(law["entry"], p.parent)
            except LawEntryError as e:
                raise ConfigError(f"{p}: law: {e}") from None
            data = {**data, "law": {**law, "entry": entry}}  # type: ignore[dict-item]
        if isinstance(data, dict) and isinstance(data.get("faults"), dict):
            data = {**data, "faults": _plan_relative_to(data["faults"], p)}
        vehicle = data.get("vehicle") if isinstance(data, dict) else None
        if isinstance(vehicle, dict) and isinstance(vehicle.get("model"), str) and ":" in vehicle["model"]:
            try:  # a vehicle model of the user's: its file is found as a law's is
                model = absolute_entry(vehicle["model"], p.parent)
            except LawEntryError as e:
                raise ConfigError(f"{p}: vehicle.model: {e}") from None
            data = {**data, "vehicle": {**vehicle, "model": model}}  # type: ignore[dict-item]
        cfg = parse_config(data, str(p), recorded)
        _LAST.clear()
        _LAST[key] = cfg
    return cfg


def section_file(p: Path, key: str) -> object:
    """A YAML file of one config section (``--faults``, ``--spec``): what goes under ``key:``,
    written with or without that key."""
    data = _read_yaml(p)
    if isinstance(data, dict) and set(data) == {key}:
        return data[key]
    return data


def with_spec(cfg: SwarmConfig, path: str | Path | None) -> SwarmConfig:
    """``cfg`` held to the requirements of the YAML file ``path`` (``--spec``: a list of
    requirements, with or without a ``spec:`` key) in place of its own; ``cfg`` itself for None."""
    if path is None:
        return cfg
    p = Path(path)
    data = section_file(p, "spec")
    if not isinstance(data, list):
        raise ConfigError(f"{p}: expected a list of requirements (name, over, formula)")
    return parse_config({**cfg.data(), "spec": data}, str(p))


def with_seed(cfg: SwarmConfig, seed: int | None) -> SwarmConfig:
    """``cfg`` with the run seed ``seed`` (``--seed``) in place of its own; ``cfg`` itself for None."""
    if seed is None:
        return cfg
    if not 0 <= seed < 2**63:
        raise ConfigError(f"--seed must be an integer from 0 to 2**63 - 1, got {seed}")
    return parse_config({**cfg.data(), "seed": seed}, "--seed")


def with_duration(cfg: SwarmConfig, duration_s: float | None) -> SwarmConfig:
    """``cfg`` with ``duration_s`` (``--duration``) in place of its own, validated again (a fault
    plan's times must fall within it); ``cfg`` itself for None."""
    if duration_s is None:
        return cfg
    if not 0 < duration_s < math.inf:
        raise ConfigError(f"--duration must be a number of seconds > 0, got {duration_s}")
    return parse_config({**cfg.data(), "duration_s": float(duration_s)}, "--duration")


def _plan_relative_to(faults: dict[str, Any], p: Path) -> dict[str, Any]:
    """A fault plan whose link models' file entries (``model: {entry}``) are made absolute
    against the directory of ``p``, the file that holds them."""
    plan = faults.get("plan")
    if not isinstance(plan, list):
        return faults
    out = []
    for f in plan:
        model = f.get("model") if isinstance(f, dict) else None
        if isinstance(model, dict) and isinstance(model.get("entry"), str):
            try:
                f = {**f, "model": {**model, "entry": absolute_entry(model["entry"], p.parent)}}
            except LawEntryError as e:
                raise ConfigError(f"{p}: faults: {e}") from None
        out.append(f)
    return {**faults, "plan": out}


def with_faults(cfg: SwarmConfig, path: str | Path) -> SwarmConfig:
    """``cfg`` with the fault plan of the YAML file ``path`` (the mapping that goes under
    ``faults:``, with or without that key) in place of its own, validated against it."""
    p = Path(path)
    data = section_file(p, "faults")
    if not isinstance(data, dict):
        raise ConfigError(f"{p}: expected a fault plan (seed, plan) at the top level")
    merged = {**cfg.data(), "faults": _plan_relative_to(data, p)}
    try:
        return SwarmConfig.model_validate(merged)
    except ValidationError as err:
        raise ConfigError(f"{p}: {_describe(err)}") from None


def plan_data(faults: Any) -> dict[str, Any] | None:
    """``faults`` as the ``faults:`` mapping: a list of entries, a mapping, or a YAML file."""
    if faults is None:
        return None
    if isinstance(faults, str | Path):
        try:
            data = yaml.safe_load(Path(faults).read_text())
        except (OSError, UnicodeDecodeError, yaml.YAMLError) as e:
            raise ConfigError(f"{faults}: cannot read the fault plan ({e})") from None
        faults = data.get("faults", data) if isinstance(data, dict) else data
    if isinstance(faults, list):
        faults = {"plan": faults}
    if not isinstance(faults, dict):
        raise ConfigError("faults: expected a list of entries, a mapping (seed, plan) or a file")
    return dict(faults)
