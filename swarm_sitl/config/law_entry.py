"""A config's ``law:`` entry made a class: imported, held to the contract, its params validated.

``entry`` is ``"package.module:Name"`` (imported as Python imports it: installed, or on
``PYTHONPATH``) or ``"path/to/file.py:Name"`` (loaded from that file; a relative path is relative to
the config file, ``load.load_config`` makes it absolute). ``resolve`` imports it once per process
and checks what can be checked before it runs (``laws.contract``): a class with a callable
``step``, a ``message_length`` from 1 to ``MAX_MESSAGE_LENGTH``, ``record_fields`` mapping names
to widths. ``validate_params`` runs the law's own ``Params`` on its ``params:`` if it declares
one. Each failure is a ``LawEntryError`` of one line that names the entry.
"""

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ValidationError

from sim_vehicles.common import entry as entry_import
from sim_vehicles.common.contract import missing_members
from sim_vehicles.common.entry import declared_params, undeclared_line
from swarm_sitl.laws.contract import MAX_MESSAGE_LENGTH, Law

#: names every follower's recording has whatever the law: a law's record may not reuse them
RESERVED_NAMES = frozenset(
    {"t_s", "sample_t_s", "p_W", "v_W", "q_WB", "omega_B", "thrust_N", "q_c", "omega_c", "omegadot_c"}
    | {"pos_err_m", "vel_err_mps", "est_pos_err_m", "est_vel_err_mps", "est_acc_err_mps2", "offset_m"}
)


class LawEntryError(ValueError):
    """A ``law:`` entry that cannot be flown; the message is one line naming it."""


_RESOLVED: dict[str, type] = {}


def split_entry(entry: str) -> tuple[str, str]:
    """``(module or file, class name)`` of ``"where:Name"``."""
    try:
        return entry_import.split_entry(entry)
    except entry_import.EntryError as e:
        raise LawEntryError(str(e)) from None


is_file_entry = entry_import.is_file_entry


def absolute_entry(entry: str, base_dir: Path) -> str:
    """A file entry's path made absolute against ``base_dir`` (any other entry as it is)."""
    try:
        return entry_import.absolute_entry(entry, base_dir)
    except entry_import.EntryError as e:
        raise LawEntryError(str(e)) from None


def _line(e: BaseException) -> str:
    return entry_import.one_line(e)


#: how a missing member of the law contract is named in the one line that says so
SAID = {"step": "step(t_s, sample, inbox) method", "message_length": "message_length (an int)"}


def check_contract(cls: Any, entry: str) -> None:
    """What the contract asks that a class shows before it runs."""
    if not isinstance(cls, type):
        raise LawEntryError(f"entry {entry!r} is a {type(cls).__name__}, not a class")
    # what the protocol declares (laws.contract.Law), and its step a method
    missing = missing_members(cls, Law) or ([] if callable(getattr(cls, "step", None)) else ["step"])
    if missing:
        said = ", ".join(SAID.get(name, name) for name in missing)
        raise LawEntryError(
            f"entry {entry!r}: class {cls.__name__} does not meet the law contract: no {said}"
        )
    n = getattr(cls, "message_length", None)
    if type(n) is not int or not 1 <= n <= MAX_MESSAGE_LENGTH:
        raise LawEntryError(
            f"entry {entry!r}: message_length must be an int from 1 to {MAX_MESSAGE_LENGTH}, got {n!r}"
        )
    fields = getattr(cls, "record_fields", None)
    if not isinstance(fields, Mapping):
        raise LawEntryError(
            f"entry {entry!r}: record_fields must be a mapping of name -> width, got {fields!r}"
        )
    for name, width in fields.items():
        if not (isinstance(name, str) and name.isidentifier()):
            raise LawEntryError(f"entry {entry!r}: record field {name!r} is not a name")
        if name in RESERVED_NAMES:
            raise LawEntryError(f"entry {entry!r}: record field {name!r} is one the bench records itself")
        if type(width) is not int or width < 1:
            raise LawEntryError(
                f"entry {entry!r}: record field {name!r} has width {width!r}, not an int >= 1"
            )


def resolve(entry: str) -> type:
    """The law class ``entry`` names, imported and checked (once per process)."""
    cls = _RESOLVED.get(entry)
    if cls is None:
        try:
            cls = entry_import.load_entry(entry, "swarm_sitl_law")
        except entry_import.EntryError as e:
            raise LawEntryError(str(e)) from None
        check_contract(cls, entry)
        _RESOLVED[entry] = cls
    return cls


def validate_params(cls: type, params: Mapping[str, Any], entry: str) -> Any:
    """``params`` through the law's ``Params`` (a pydantic model, or any class taking them as
    keywords: a dataclass, a NamedTuple); a law that declares none takes none. A name its
    ``Params`` does not declare is refused here, whatever the model itself would accept."""
    schema = getattr(cls, "Params", None)
    unknown = undeclared_line(params, frozenset() if schema is None else declared_params(schema), "it")
    if unknown is not None:  # (whatever the law's own Params would let through)
        raise LawEntryError(f"params: {unknown} (law {entry})")
    if schema is None:
        return dict(params)
    try:
        if isinstance(schema, type) and issubclass(schema, BaseModel):
            return schema.model_validate(dict(params))
        return schema(**params)
    except ValidationError as e:
        err = e.errors()[0]
        where = ".".join(str(p) for p in err["loc"])
        msg = err["msg"].removeprefix("Value error, ")
        raise LawEntryError(f"params{'.' + where if where else ''}: {msg} (law {entry})") from None
    except (TypeError, ValueError) as e:
        raise LawEntryError(f"params: {_line(e)} (law {entry})") from None
