"""The code base's layout: concept folders that say what they may import, and imports that keep
to it. Each folder's ``__init__.py`` docstring ends with ``May import: ...`` (folders of its own
package by name, the other package's as ``sim_vehicles.<folder>`` or whole as ``sim_vehicles``);
the top of a package (its ``__init__``, ``__main__`` and, in ``swarm_sitl``, ``cli``, ``api`` and
``pytest_plugin``) may import any of its folders, and no folder may import it. Every import counts,
at the top of a module or inside a function, for typing or not."""

import ast
import re
from functools import cache
from pathlib import Path

import pytest

from tests.support import ROOT

pytestmark = pytest.mark.unit

PACKAGES = ("sim_vehicles", "swarm_sitl")
MAX_LINES = 500
#: what the pure laws may not import: sockets, processes, clocks, files, middleware, logging
IO_MODULES = {"socket", "select", "zenoh", "pymavlink", "subprocess", "time", "logging", "os", "threading"}
PURE_FOLDERS = ("swarm_sitl.laws", "sim_vehicles.plant")


@cache
def _modules() -> dict[str, Path]:
    """Every module of ours by dotted name (a package by its own name)."""
    out = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def _resolve(name: str) -> str | None:
    """The module of ours ``name`` is, or is in."""
    mods = _modules()
    while name and name not in mods:
        name = name.rpartition(".")[0]
    return name or None


@cache
def _imports(module: str) -> frozenset[str]:
    """The modules of ours ``module`` imports, anywhere in it (a package it only imports a module
    from, ``from pkg import mod``, is not counted)."""
    found = set()
    for node in ast.walk(ast.parse(_modules()[module].read_text())):
        targets: list[str | None] = []
        if isinstance(node, ast.Import):
            targets = [_resolve(a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            for a in node.names:
                full = f"{node.module}.{a.name}"
                targets.append(full if full in _modules() else _resolve(node.module))
        found |= {t for t in targets if t and t != module and not module.startswith(t + ".")}
    return frozenset(found)


def _folder(module: str) -> str:
    """``sim_vehicles.plant`` for ``sim_vehicles.plant.autopilot``; a package's top modules are
    the package's own (``swarm_sitl`` for ``swarm_sitl.cli``)."""
    parts = module.split(".")
    path = _modules()[module]
    if len(parts) >= 2 and (ROOT / parts[0] / parts[1]).is_dir() and path.parent != ROOT / parts[0]:
        return ".".join(parts[:2])
    return parts[0]


def _folders() -> list[str]:
    return sorted({_folder(m) for m in _modules()} - set(PACKAGES))


@cache
def _may_import(folder: str) -> frozenset[str]:
    """The folders ``folder``'s docstring says it may import (a whole package: its folders and top)."""
    doc = ast.get_docstring(ast.parse((ROOT / folder.replace(".", "/") / "__init__.py").read_text())) or ""
    m = re.search(r"May import: (.+?)\.\s*$", doc, re.S)
    assert m, f"{folder}/__init__.py: the docstring does not end with 'May import: ...'"
    text = " ".join(m.group(1).split())
    if text == "nothing of ours":
        return frozenset()
    package = folder.split(".")[0]
    out = set()
    for name in (n.strip() for n in text.split(",")):
        full = name if name.split(".")[0] in PACKAGES else f"{package}.{name}"
        if full in PACKAGES:
            out |= {f for f in _folders() if f.startswith(full + ".")} | {full}
        else:
            out.add(full)
    return frozenset(out)


def test_every_folder_says_what_it_may_import_and_names_only_folders():
    folders = _folders()
    assert len(folders) >= 10
    for folder in folders:
        for allowed in _may_import(folder):
            assert allowed in folders or allowed in PACKAGES, f"{folder} may import {allowed}: no such folder"


def test_every_import_is_one_its_folder_may_make():
    bad = []
    for module in _modules():
        here = _folder(module)
        for target in _imports(module):
            there = _folder(target)
            if there == here or (here in PACKAGES and there.split(".")[0] == here):
                continue  # within a folder; a package's top over its own folders
            if here in PACKAGES or there not in _may_import(here):
                bad.append(f"{module} imports {target}")
    assert not bad, "imports their folders may not make:\n" + "\n".join(bad)


def test_the_folders_have_an_order():
    """What the folders may import is a ranking: no two folders may import each other, through
    any chain."""
    order: list[str] = []
    left = set(_folders())
    while left:
        ready = sorted(f for f in left if not (_may_import(f) - set(PACKAGES)) & left)
        assert ready, f"the folders {sorted(left)} may import each other in a circle"
        order += ready
        left -= set(ready)
    assert (
        order.index("sim_vehicles.common")
        < order.index("swarm_sitl.laws")
        < order.index("swarm_sitl.running")
    )


def test_no_module_imports_itself_back():
    """No import circle between modules, at the top of a module or inside a function."""
    graph = {m: _imports(m) for m in _modules()}
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> None:
        state[m] = 1
        stack.append(m)
        for t in sorted(graph[m]):
            if state.get(t) == 1:
                circle = [*stack[stack.index(t) :], t]
                raise AssertionError("import circle: " + " -> ".join(circle))
            if t not in state:
                visit(t)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)


def test_no_module_is_over_500_lines():
    sizes = {m: len(p.read_text().splitlines()) for m, p in _modules().items()}
    big = {m: n for m, n in sizes.items() if n > MAX_LINES}
    assert not big, f"modules over {MAX_LINES} lines: {big}"


def test_the_pure_laws_import_no_io():
    for module, path in _modules().items():
        if _folder(module) not in PURE_FOLDERS:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            for name in names:
                assert name.split(".")[0] not in IO_MODULES, f"{module} imports {name}"


def test_sim_vehicles_does_not_depend_on_the_swarm():
    bad = [
        (m, t)
        for m in _modules()
        if m.startswith("sim_vehicles")
        for t in _imports(m)
        if t.startswith("swarm_sitl")
    ]
    assert not bad, f"sim_vehicles must be usable alone: {bad}"


def test_the_docs_index_maps_every_folder():
    """The layout section of ``docs/README.md`` names every folder of the tree, once, and no other."""
    text = (ROOT / "docs" / "README.md").read_text()
    m = re.search(r"## The code, folder by folder\n.*?```\n(.*?)```", text, re.S)
    assert m, "docs/README.md has no '## The code, folder by folder' section with a code block"
    listed, package = [], ""
    for line in m.group(1).splitlines():
        name = line.split()[0] if line.strip() else ""
        if not name.endswith("/"):
            continue
        if not line.startswith(" "):
            package = name.rstrip("/")
            listed.append(package)
        else:
            listed.append(f"{package}.{name.rstrip('/')}" if package in PACKAGES else f"{package}/{name}")
    tree = [*PACKAGES, *_folders()]
    ours = [n for n in listed if n.split(".")[0] in PACKAGES]
    assert sorted(ours) == sorted(tree), f"docs/README.md lists {sorted(ours)}, the tree has {sorted(tree)}"
    others = [n for n in listed if n.split(".")[0] not in PACKAGES]
    gone = [n for n in others if not (ROOT / n).is_dir()]
    assert not gone, f"docs/README.md lists folders that do not exist: {gone}"


def test_every_folder_docstring_names_each_of_its_modules():
    """A folder's ``__init__`` says what it holds: each module (and, for a package, each folder)
    is named in it, so a newcomer finds a module from its folder's docstring."""
    missing = []
    for init in sorted(p for package in PACKAGES for p in (ROOT / package).rglob("__init__.py")):
        doc = ast.get_docstring(ast.parse(init.read_text())) or ""
        names = [p.stem for p in init.parent.glob("*.py") if p.stem != "__init__"]
        names += [d.name for d in init.parent.iterdir() if (d / "__init__.py").is_file()]
        folder = init.parent.relative_to(ROOT)
        missing += [f"{folder}/{n}" for n in names if not re.search(rf"\b{re.escape(n)}\b", doc)]
    assert not missing, f"modules their folder's docstring does not name: {missing}"


def test_every_file_of_the_packages_that_is_not_python_is_installed():
    """The tests run the commands from the checkout (``tests/cli_host.py``), so a data file the
    install leaves out would pass them: each tracked file of the packages that is not a module is
    matched by ``pyproject.toml``'s package data (the page's assets, the ROS 2 messages)."""
    import fnmatch
    import subprocess
    import tomllib

    data = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]
    globs = [f"{package.replace('.', '/')}/{g}" for package, gs in data.items() for g in gs]
    tracked = subprocess.run(
        ["git", "ls-files", *PACKAGES], cwd=ROOT, capture_output=True, text=True, check=True
    ).stdout.split()
    if not tracked:
        pytest.skip("not a git checkout: no list of the tracked files")
    left_out = [f for f in tracked if not f.endswith(".py") and not any(fnmatch.fnmatch(f, g) for g in globs)]
    assert not left_out, f"not in [tool.setuptools.package-data]: {left_out}"
    assert all(any(fnmatch.fnmatch(f, g) for f in tracked) for g in globs), globs  # (no stale glob)
