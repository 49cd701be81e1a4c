"""A plug-in named by an entry, imported: ``"package.module:Name"`` (imported as Python imports
it: installed, or on ``PYTHONPATH``) or ``"path/to/file.py:Name"`` (loaded from that file).

Both packages' plug-in points use it: a law (``swarm_sitl.config.law_entry``), a vehicle model
(``sim_vehicles.models.build``) and a link model (``swarm_sitl.faults.link_model``), and each
holds a plug-in's parameters to the names it declares (``declared_params``, ``undeclared_line``),
whatever the plug-in's own code would accept. A file is loaded once per process under a module name made of
its stem and a hash of its path, so two plug-ins in files of one name coexist; a file whose
import fails is forgotten, so the fixed file loads in the same process. Each failure is an
``EntryError`` of one line naming the entry.
"""

import dataclasses
import hashlib
import importlib
import importlib.util
import inspect
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any


class EntryError(ValueError):
    """An entry that cannot be imported; the message is one line naming it."""


def split_entry(entry: str) -> tuple[str, str]:
    """``(module or file, name)`` of ``"where:Name"``."""
    where, sep, name = entry.rpartition(":")
    if not sep or not where or not name.isidentifier():
        raise EntryError(f"entry {entry!r} must be 'package.module:ClassName' or 'path/file.py:ClassName'")
    return where, name


def is_file_entry(entry: str) -> bool:
    return entry.rpartition(":")[0].endswith(".py")


def absolute_entry(entry: str, base_dir: Path) -> str:
    """A file entry's path made absolute against ``base_dir`` (any other entry as it is)."""
    if not is_file_entry(entry):
        return entry
    where, name = split_entry(entry)
    path = Path(where)
    return entry if path.is_absolute() else f"{(base_dir / path).resolve()}:{name}"


def one_line(e: BaseException) -> str:
    text = " ".join(str(e).split())
    return f"{type(e).__name__}: {text}" if text else type(e).__name__


def import_where(entry: str, where: str, prefix: str) -> Any:
    """The module ``where`` of ``entry`` names (a file's under ``prefix_<stem>_<hash>``)."""
    if where.endswith(".py"):
        path = Path(where)
        if not path.is_file():
            raise EntryError(f"entry {entry!r}: no such file {path}")
        digest = hashlib.sha256(str(path.resolve()).encode()).hexdigest()[:12]
        mod_name = f"{prefix}_{path.stem}_{digest}"
        if mod_name in sys.modules:
            return sys.modules[mod_name]
        spec = importlib.util.spec_from_file_location(mod_name, path)
        if spec is None or spec.loader is None:
            raise EntryError(f"entry {entry!r}: {path} cannot be loaded as Python")
        module = importlib.util.module_from_spec(spec)
        sys.modules[mod_name] = module
        try:
            spec.loader.exec_module(module)
        except BaseException as e:
            del sys.modules[mod_name]
            raise EntryError(f"entry {entry!r}: importing {path} failed: {one_line(e)}") from None
        return module
    try:
        return importlib.import_module(where)
    except ModuleNotFoundError as e:
        raise EntryError(f"entry {entry!r}: no module named {e.name!r}") from None
    except BaseException as e:
        raise EntryError(f"entry {entry!r}: importing {where} failed: {one_line(e)}") from None


def load_entry(entry: str, prefix: str) -> Any:
    """The object ``entry`` names (``prefix``: of a file's module name)."""
    where, name = split_entry(entry)
    module = import_where(entry, where, prefix)
    if not hasattr(module, name):
        raise EntryError(f"entry {entry!r}: {where} has no {name!r}")
    return getattr(module, name)


def declared_params(schema: Any) -> frozenset[str] | None:
    """The parameter names a plug-in's ``Params`` declares: a pydantic model's fields and their
    aliases, a dataclass's or NamedTuple's fields, or the keyword parameters of any other class
    (None where it takes any keyword: ``**kwargs``)."""
    fields = getattr(schema, "model_fields", None)
    if isinstance(fields, dict):  # a pydantic model
        names = set(fields)
        for info in fields.values():
            names |= {a for a in (info.alias, info.validation_alias) if isinstance(a, str)}
        return frozenset(names)
    if dataclasses.is_dataclass(schema):
        return frozenset(f.name for f in dataclasses.fields(schema))
    if hasattr(schema, "_fields"):  # a NamedTuple
        return frozenset(schema._fields)
    try:
        parameters = inspect.signature(schema).parameters.values()
    except (TypeError, ValueError):
        return None
    if any(p.kind is p.VAR_KEYWORD for p in parameters):
        return None
    return frozenset(p.name for p in parameters if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY))


def undeclared_line(given: Iterable[str], declared: frozenset[str] | None, what: str) -> str | None:
    """One line naming the parameters of ``given`` that ``declared`` does not have (None: all
    are declared, or the plug-in takes any): ``what`` names the plug-in."""
    if declared is None:
        return None
    unknown = sorted(str(k) for k in given if k not in declared)
    if not unknown:
        return None
    has = f"it has {', '.join(sorted(declared))}" if declared else "it declares none"
    return f"{what} has no parameter {', '.join(unknown)} ({has})"
