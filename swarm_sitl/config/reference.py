"""The config reference (``docs/config.md``), generated from the schema: ``SwarmConfig`` and the
sections it holds, each read from the module that defines it.

Every key of a config file, with its type, default and meaning: the meaning is the ``#:`` comment
on or above the field in the source (or the section's docstring), so the schema is the only place
it is written. ``python -m swarm_sitl.config.reference > docs/config.md`` writes it;
``tests/test_config_reference.py`` fails when the file is not what the schema gives.
"""

import ast
import inspect
import sys
import types
import typing
from typing import Any

from pydantic import BaseModel

from swarm_sitl.config.schema import SwarmConfig


def _comments(module: types.ModuleType) -> dict[tuple[str, str], str]:
    """``(class, field) -> text`` of the ``#:`` comments on or just above each field."""
    src = inspect.getsource(module)
    lines = src.splitlines()
    out: dict[tuple[str, str], str] = {}
    for node in ast.walk(ast.parse(src)):
        if not isinstance(node, ast.ClassDef):
            continue
        for stmt in node.body:
            if not (isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name)):
                continue
            row = stmt.lineno - 1
            above: list[str] = []
            j = row - 1
            while j >= 0 and lines[j].strip().startswith("#:"):
                above.insert(0, lines[j].strip()[2:].strip())
                j -= 1
            trailing = lines[stmt.end_lineno - 1].partition("  #:")[2].strip() if stmt.end_lineno else ""
            text = " ".join([*above, trailing]).strip()
            if text:
                out[(node.name, stmt.target.id)] = text
    return out


def _type(annotation: Any) -> str:
    """A short, readable type."""
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if origin is typing.Annotated:
        return _type(args[0])
    if origin is typing.Literal:
        return " \\| ".join(repr(a) for a in args)
    if origin in (typing.Union, types.UnionType):
        return " \\| ".join(_type(a) for a in args)
    if origin in (list, tuple):
        inner = ", ".join("..." if a is Ellipsis else _type(a) for a in args)
        return f"{origin.__name__}[{inner}]"
    if annotation is type(None):
        return "null"
    return getattr(annotation, "__name__", str(annotation))


def _models(annotation: Any) -> list[type[BaseModel]]:
    """The config sections an annotation holds (through lists, unions and ``Annotated``)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    return [m for a in typing.get_args(annotation) for m in _models(a)]


def _default(field: Any) -> str:
    if field.is_required():
        return "required"
    value = field.get_default(call_default_factory=True)
    if isinstance(value, BaseModel):
        return "(section)"
    return f"`{value!r}`" if not isinstance(value, str) else f'`"{value}"`'


def _section(model: type[BaseModel], path: str, docs: dict[tuple[str, str], str], out: list[str]) -> None:
    doc = inspect.cleandoc(model.__doc__ or "")  # (a class's docstring is its own: None if it has none)
    out += [f"## `{path}`" if path else "## top level", ""]
    if doc:
        out += [doc, ""]
    out += ["| key | type | default | meaning |", "|---|---|---|---|"]
    nested: list[tuple[type[BaseModel], str]] = []
    for name, field in model.model_fields.items():
        meaning = docs.get((model.__name__, name), "").replace("|", "\\|")
        out.append(f"| `{name}` | {_type(field.annotation)} | {_default(field)} | {meaning} |")
        for sub in _models(field.annotation):
            many = typing.get_origin(field.annotation) is list
            key = f"{path}.{name}" if path else name
            kind = sub.model_fields.get("type")
            if kind is not None and typing.get_origin(kind.annotation) is typing.Literal:
                key += f" (type: {typing.get_args(kind.annotation)[0]})"
            nested.append((sub, key + ("[]" if many else "")))
    out.append("")
    for sub, key in nested:
        _section(sub, key, docs, out)


def _sections(model: type[BaseModel]) -> list[type[BaseModel]]:
    """``model`` and every section under it, each once, in the order they are written."""
    out = [model]
    for field in model.model_fields.values():
        for sub in _models(field.annotation):
            out += [m for m in _sections(sub) if m not in out]
    return out


def reference() -> str:
    modules = list(dict.fromkeys(sys.modules[m.__module__] for m in _sections(SwarmConfig)))
    docs = {k: v for module in modules for k, v in _comments(module).items()}
    files = ", ".join(f"`{m.__name__.replace('.', '/')}.py`" for m in modules)
    out = [
        "# Config reference",
        "",
        f"Generated from the schema ({files}) by",
        "`python -m swarm_sitl.config.reference > docs/config.md`; do not edit by hand. Units are in",
        "the key names (`_m`, `_s`, `_hz`, `_kg`, `_N`, `_rps`); vectors are ENU, quaternions",
        "`[w, x, y, z]` body (FLU) to world. Unknown keys are errors; `swarm-sitl check CONFIG` validates",
        "a file.",
        "",
    ]
    _section(SwarmConfig, "", docs, out)
    return "\n".join(out).rstrip() + "\n"


if __name__ == "__main__":
    sys.stdout.write(reference())
