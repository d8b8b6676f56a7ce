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


# --------------------------------------------------------------------------- import cycles

CYCLE_PACKAGES = ("granularsap", "lammps_bridge")


def _our_modules():
    """{dotted name: path} of every module of granularsap and lammps_bridge."""
    out = {}
    for pkg in CYCLE_PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            out[".".join(_dotted(path))] = path
    return out


def _import_edges(path, modules):
    """The modules of ``modules`` that the module at ``path`` can import, at any depth.

    The rule (every edge is one a run may take, whether or not it is taken on import):

    - every ``import a.b`` and ``from a.b import c`` anywhere in the module: at module
      level, inside functions and methods (lazy imports), under ``try``/``if``;
    - ``from pkg import name`` is an edge to ``pkg.name`` when that is a module of ours,
      else to ``pkg`` (its ``__init__``); ``import a.b.c`` is an edge to ``a.b.c``.  The
      parents a submodule import also runs are not edges: Python has them in
      ``sys.modules`` before the child runs, so they cannot close a cycle of their own;
    - every string constant that equals the dotted name of one of our modules and has a
      dot in it (``"granularsap.io.cli_contacts"`` in a table of subcommands loaded with
      ``importlib.import_module``, an ``exc.name`` compared to a module): a module named
      by a string can be loaded by it.  Bare package names (``"granularsap"``) are
      skipped: they are program, logger and distribution names far more often than
      imports.
    """
    tree = ast.parse(path.read_text(), filename=str(path))
    here = ".".join(_dotted(path))
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            mod = _resolve(path, node)
            if not _ours(mod):
                continue
            for alias in node.names:
                sub = ".".join(mod + [alias.name])
                found.add(sub if sub in modules else ".".join(mod))
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if _ours(alias.name.split(".")):
                    found.add(alias.name)
        elif (isinstance(node, ast.Constant) and isinstance(node.value, str)
                and "." in node.value and node.value in modules):
            found.add(node.value)
    return {m for m in found if m in modules and m != here}


def _graph(modules):
    return {name: _import_edges(path, modules) for name, path in modules.items()}


def _cycles(graph):
    """Import cycles as paths ``[a, b, ..., a]``: for every module on a cycle, the shortest
    cycle through it (breadth first), each cycle once."""
    seen = set()
    out = []
    for start in sorted(graph):
        parent = {start: None}
        queue = [start]
        closing = None
        while queue and closing is None:
            nxt = []
            for node in queue:
                for to in sorted(graph[node]):
                    if to == start:
                        closing = node
                        break
                    if to not in parent:
                        parent[to] = node
                        nxt.append(to)
                if closing is not None:
                    break
            queue = nxt
        if closing is None:
            continue
        path = [closing]
        while parent[path[-1]] is not None:
            path.append(parent[path[-1]])
        path = path[::-1]  # start ... closing
        key = frozenset(zip(path, path[1:] + [start], strict=True))
        if key not in seen:
            seen.add(key)
            out.append(path + [start])
    return out


def test_no_import_cycles_through_lazy_imports():
    """No module of ours can import itself back, counting imports inside functions and
    modules named by strings (see :func:`_import_edges` for the rule)."""
    cycles = _cycles(_graph(_our_modules()))
    assert [" -> ".join(c) for c in cycles] == []


def test_the_cycle_checker_catches_lazy_and_string_cycles(tmp_path, monkeypatch):
    pkg = tmp_path / "granularsap"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("from .core import thing\n")
    (pkg / "core.py").write_text("thing = 1\n")
    # a lazy cycle: front imports back at module level, back imports front in a function
    (pkg / "front.py").write_text("from . import back\n")
    (pkg / "back.py").write_text("def f():\n    from .front import g\n    return g\n")
    # an importlib cycle: a table of module names, and the module importing the table back
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "sub" / "table.py").write_text(
        "import importlib\n"
        "COMMANDS = {'go': ('granularsap.sub.command', 'help')}\n"
        "def load(name):\n    return importlib.import_module(COMMANDS[name][0])\n")
    (pkg / "sub" / "command.py").write_text(
        "def run():\n    from granularsap.sub.table import COMMANDS\n    return COMMANDS\n")
    # not cycles: a parent package, a bare package name as a string, a leaf imported by both
    (pkg / "leaf.py").write_text("NAME = 'granularsap'\n")
    (pkg / "user.py").write_text("import granularsap.leaf\nfrom granularsap import core\n")
    monkeypatch.setitem(globals(), "ROOT", tmp_path)
    monkeypatch.setitem(globals(), "CYCLE_PACKAGES", ("granularsap",))
    modules = _our_modules()
    graph = _graph(modules)
    assert graph["granularsap.back"] == {"granularsap.front"}
    assert graph["granularsap.sub.table"] == {"granularsap.sub.command"}
    assert graph["granularsap.user"] == {"granularsap.leaf", "granularsap.core"}
    assert graph["granularsap.leaf"] == set()
    cycles = {" -> ".join(c) for c in _cycles(graph)}
    assert cycles == {"granularsap.back -> granularsap.front -> granularsap.back",
                      "granularsap.sub.command -> granularsap.sub.table -> "
                      "granularsap.sub.command"}


def _is_alias(path):
    doc = ast.get_docstring(ast.parse(path.read_text())) or ""
    return doc.startswith("Alias of ")


def test_the_library_does_not_import_the_command_line():
    """The command line (granularsap.cli) sits above the library: no module outside it
    imports it, lazily or by name, except its leaf ``granularsap.cli.errors``; the leaves
    ``errors`` and ``argtypes`` import nothing of ours.  ``granularsap.__main__`` and the
    aliases kept for one release (modules whose docstring starts with "Alias of ") are
    faces themselves."""
    modules = _our_modules()
    graph = _graph(modules)
    found = []
    for name, edges in sorted(graph.items()):
        if name.startswith("granularsap.cli.") or name in ("granularsap.cli",
                                                           "granularsap.__main__"):
            continue
        if _is_alias(modules[name]):
            continue
        for to in sorted(edges):
            if (to == "granularsap.cli" or to.startswith("granularsap.cli.")) \
                    and to != "granularsap.cli.errors":
                found.append(f"{name} -> {to}")
    for leaf in ("granularsap.cli.errors", "granularsap.cli.argtypes"):
        found.extend(f"{leaf} -> {to}" for to in sorted(graph[leaf]))
    assert found == []
