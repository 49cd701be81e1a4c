"""A run's plug-ins kept with it, so its run directory reads and flies again anywhere.

The plug-ins of a config (``entries``): its law (``law.entry``), its vehicle model
(``vehicle.model``) and each link model of its plan (``faults.plan[j].model.entry``). ``pack``
takes a config's data and gives it back with every **file** entry naming a copy under
``plugins/`` (``plugins/my_law.py:MyLaw``, relative to where the config is written), with the
copies' bytes. A **package** entry outside ``swarm_sitl`` and ``sim_vehicles`` keeps its name (its
package must be installed to fly it again; a module copied out of its package would lose its
relative imports) and its module file is copied for the record. Ours are the package's version
(``provenance``).

``keep(cfg, run_dir)`` writes the copies into ``RUN_DIR/plugins/`` and ``RUN_DIR/plugins.json``:
each plug-in's entry as flown, its copy and the copy's SHA-256, and the law's interface
(``message_length``, ``record_fields``), so that ``plot``, ``export`` and ``merge`` read a run
without importing any plug-in (``config.load.load_recorded``). It returns the text of the
``config.yaml`` that names the copies: ``swarm-sitl run RUN_DIR/config.yaml`` flies the run again
from the run directory alone. A law file that imports modules of its own beside it needs them
importable where it flies again (a package, or ``PYTHONPATH``): only the entry's file is kept.
"""

import hashlib
import importlib.util
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

from sim_vehicles.common.entry import is_file_entry, split_entry
from swarm_sitl.rundir.whole_files import WriteError, whole, write_text_whole

PLUGINS_DIR = "plugins"  #: the copies, in the run directory
MANIFEST = "plugins.json"
OURS = ("swarm_sitl", "sim_vehicles")


def source_file(entry: str) -> Path | None:
    """The file a plug-in entry's code is in (None: it cannot be found)."""
    where, _ = split_entry(entry)
    if is_file_entry(entry):
        return Path(where)
    try:
        spec = importlib.util.find_spec(where)
    except (ImportError, ValueError):
        return None
    return Path(spec.origin) if spec is not None and spec.origin else None


def file_sha256(path: Path | None) -> str | None:
    if path is None or not path.is_file():
        return None
    return hashlib.sha256(path.read_bytes()).hexdigest()


def entries(data: dict[str, Any]) -> dict[str, str]:
    """``what -> entry`` of each plug-in a config's data names (``law``, ``vehicle``,
    ``faults.plan.<j>``)."""
    out = {"law": str(data.get("law", {}).get("entry", ""))}
    model = data.get("vehicle", {}).get("model", "")
    if isinstance(model, str) and ":" in model:
        out["vehicle"] = model
    plan = data.get("faults", {}).get("plan", []) or []
    for j, f in enumerate(plan):
        m = f.get("model") if isinstance(f, dict) else None
        if isinstance(m, dict) and isinstance(m.get("entry"), str):
            out[f"faults.plan.{j}"] = m["entry"]
    return {k: v for k, v in out.items() if v}


def _is_ours(entry: str) -> bool:
    return not is_file_entry(entry) and split_entry(entry)[0].split(".")[0] in OURS


def _named(data: dict[str, Any], what: str, entry: str) -> dict[str, Any]:
    """``data`` with plug-in ``what`` named ``entry``."""
    data = json.loads(json.dumps(data))  # a deep copy of plain data
    if what == "law":
        data["law"]["entry"] = entry
    elif what == "vehicle":
        data["vehicle"]["model"] = entry
    else:
        data["faults"]["plan"][int(what.rsplit(".", 1)[1])]["model"]["entry"] = entry
    return data


def pack(data: dict[str, Any]) -> tuple[dict[str, Any], dict[str, bytes], dict[str, Any]]:
    """``(data naming the copies, {relative path: bytes}, manifest)`` (module docstring)."""
    files: dict[str, bytes] = {}
    manifest: dict[str, Any] = {}
    for what, entry in entries(data).items():
        if _is_ours(entry):  # the package's version says it; hashed all the same
            manifest[what] = {"entry": entry, "kept": None, "sha256": file_sha256(source_file(entry))}
            continue
        src = source_file(entry)
        if src is None or not src.is_file():
            manifest[what] = {"entry": entry, "kept": None, "sha256": None}
            continue
        body = src.read_bytes()
        digest = hashlib.sha256(body).hexdigest()
        name = f"{src.stem}.py"
        rel = f"{PLUGINS_DIR}/{name}"
        if rel in files and files[rel] != body:  # another plug-in's file of the same name
            rel = f"{PLUGINS_DIR}/{src.stem}_{digest[:8]}.py"
        files[rel] = body
        manifest[what] = {"entry": entry, "kept": rel, "sha256": digest}
        if is_file_entry(entry):
            data = _named(data, what, f"{rel}:{split_entry(entry)[1]}")
    return data, files, manifest


def pack_with_models(
    data: dict[str, Any], models: Sequence[str]
) -> tuple[dict[str, Any], dict[str, bytes], dict[str, str]]:
    """``pack(data)`` with the files of ``models`` (users' link models by file entry that no
    entry of ``data``'s plan names: what a sweep varies or a search searches) packed beside, one
    copy per file; the third item maps each of ``models`` to its copy's entry."""
    plan = data["faults"]["plan"]
    extra = [{"model": {"entry": m}} for m in models]
    packed, files, _ = pack({**data, "faults": {**data["faults"], "plan": [*plan, *extra]}})
    copies = [f["model"]["entry"] for f in packed["faults"]["plan"][len(plan) :]]
    packed["faults"] = {**packed["faults"], "plan": packed["faults"]["plan"][: len(plan)]}
    return packed, files, dict(zip(models, copies, strict=True))


def keep(cfg: Any, run_dir: Path) -> str:
    """Copy ``cfg``'s plug-ins into ``run_dir`` and write its ``plugins.json``; the text of the
    ``config.yaml`` that names the copies. A config read from ``run_dir`` itself (``merge``) is
    kept as it is: its ``config.yaml`` text, its plug-ins and their record untouched."""
    if cfg.is_recorded:
        return (run_dir / "config.yaml").read_text()
    data, files, manifest = pack(cfg.data())
    for rel, body in files.items():
        path = run_dir / rel
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise WriteError(e.errno, f"cannot write {path.parent} ({e.strerror or e})") from e
        if not (path.is_file() and path.read_bytes() == body):
            with whole(path) as tmp:
                tmp.write_bytes(body)
    law = cfg.law_class()
    manifest["law"] = {
        **manifest.get("law", {"entry": cfg.law.entry, "kept": None, "sha256": None}),
        "message_length": int(law.message_length),
        "record_fields": {str(k): int(v) for k, v in law.record_fields.items()},
    }
    write_text_whole(run_dir / MANIFEST, json.dumps(manifest, indent=1) + "\n")
    return yaml.safe_dump(data, sort_keys=False)


def manifest_of(run_dir: Path) -> dict[str, Any]:
    """``plugins.json`` of a run directory (empty: none, from before it)."""
    try:
        data = json.loads((run_dir / MANIFEST).read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def recorded_law(run_dir: Path) -> dict[str, Any] | None:
    """The law's interface as ``keep`` recorded it (None: a run directory from before it)."""
    try:
        law = json.loads((run_dir / MANIFEST).read_text())["law"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return law if isinstance(law, dict) and isinstance(law.get("record_fields"), dict) else None
