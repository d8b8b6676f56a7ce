"""Adapters reach the engine through public names only.

Read every module of the package (granularsap, lammps_bridge, examples) and fail
on an import of another module's private name (``from .particles import
_search``), on an attribute access to a private name of an imported module
(``periodic._complete_cell``), and on a private module imported from outside
its own package (``lammps_bridge`` importing ``granularsap._validate``).
"""

from __future__ import annotations

import ast
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent
PACKAGES = ("granularsap", "lammps_bridge", "examples")


def _modules():
    for pkg in PACKAGES:
        yield from sorted((ROOT / pkg).rglob("*.py"))


def _dotted(path):
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return parts


def _resolve(path, node):
    """Absolute dotted module of an ImportFrom inside ``path``."""
    if node.level == 0:
        return (node.module or "").split(".")
    here = _dotted(path)
    if path.name != "__init__.py":
        here = here[:-1]
    base = here[:len(here) - (node.level - 1)] if node.level > 1 else here
    return base + (node.module.split(".") if node.module else [])


def _private(name):
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _ours(parts):
    return bool(parts) and parts[0] in ("granularsap", "lammps_bridge")


def _is_module(parts):
    base = ROOT.joinpath(*parts)
    return base.with_suffix(".py").exists() or (base / "__init__.py").exists()


def _outside(mod, here_pkg):
    """A private module imported from outside the package that holds it."""
    for k in range(1, len(mod)):
        if _private(mod[k]):
            parent = mod[:k]
            return here_pkg[:len(parent)] != parent
    return False


def _violations(path):
    tree = ast.parse(path.read_text(), filename=str(path))
    here = _dotted(path)
    here_pkg = here if path.name == "__init__.py" else here[:-1]
    found = []
    module_names = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            mod = _resolve(path, node)
            if not _ours(mod):
                continue
            if mod == here:
                continue
            for alias in node.names:
                if _private(alias.name) and _is_module(mod + [alias.name]):
                    if _outside(mod + [alias.name], here_pkg):
                        found.append(f"{path.name}:{node.lineno} imports private module "
                                     f"{'.'.join(mod + [alias.name])} from outside its "
                                     "package")
                elif _private(alias.name):
                    found.append(f"{path.name}:{node.lineno} imports private name "
                                 f"{alias.name} from {'.'.join(mod)}")
                else:
                    module_names[alias.asname or alias.name] = mod + [alias.name]
            if _outside(mod, here_pkg):
                found.append(f"{path.name}:{node.lineno} imports private module "
                             f"{'.'.join(mod)} from outside its package")
        elif isinstance(node, ast.Import):
            for alias in node.names:
                mod = alias.name.split(".")
                if _ours(mod):
                    module_names[alias.asname or mod[0]] = mod if alias.asname else mod[:1]
                    if _outside(mod, here_pkg):
                        found.append(f"{path.name}:{node.lineno} imports private module "
                                     f"{alias.name} from outside its package")
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                and node.value.id in module_names and _private(node.attr)):
            found.append(f"{path.name}:{node.lineno} uses private name "
                         f"{node.value.id}.{node.attr}")
    return found


@pytest.mark.parametrize("path", list(_modules()), ids=lambda p: str(p.relative_to(ROOT)))
def test_no_private_names_across_modules(path):
    assert _violations(path) == []


def test_the_checker_catches_what_it_should(tmp_path, monkeypatch):
    pkg = tmp_path / "lammps_bridge"
    pkg.mkdir(parents=True)
    bad = pkg / "bad.py"
    bad.write_text("from granularsap.particles import _search\n"
                   "from granularsap import periodic\n"
                   "from granularsap._validate import as_coords\n"
                   "from ._cell import thing\n"
                   "x = periodic._complete_cell\n")
    monkeypatch.setitem(globals(), "ROOT", tmp_path)
    found = _violations(bad)
    assert any("private name _search" in f for f in found)
    assert any("private module granularsap._validate" in f for f in found)
    assert any("periodic._complete_cell" in f for f in found)
    assert not any("_cell from" in f or "lammps_bridge._cell" in f for f in found)
