"""Each kernel compiles once per kind of frame, not once per call site.

numba types a constant argument (``0``, ``1``, ``False``, a module constant, a
variable first assigned ``0``) as a literal, so a kernel calling a compiled
helper with ``f(0, n)`` in one place and ``f(lo, n)`` in another compiles the
helper twice (a loop-carried ``cnt = 0`` passed as ``f(cnt)`` does it alone);
a ``numba.prange`` index is unsigned in the parallel build and signed in its
serial twin, so passing it straight to a helper compiles that helper twice
too.  Each copy costs seconds on a cold cache (``granularsap warmup``
compiled 19 such copies before this was checked).  Helpers inlined by
``ijit`` compile inside their caller and are exempt.

This reads the source of every kernel (no compilation) and fails on a literal,
a constant or a bare prange index passed to a helper that compiles on its own.
"""

from __future__ import annotations

import ast
import importlib
import importlib.util
import inspect
import pathlib
import re
import textwrap

import pytest
from numba.core.registry import CPUDispatcher

MODULES = [
    "granularsap._memory",
    "granularsap.bench.celllist",
    "granularsap.kernels.boxgrid",
    "granularsap.kernels.checks",
    "granularsap.kernels.common",
    "granularsap.kernels.cross",
    "granularsap.kernels.ghosts",
    "granularsap.kernels.grid",
    "granularsap.kernels.identity",
    "granularsap.kernels.listed",
    "granularsap.kernels.query",
    "granularsap.kernels.radixsort",
    "granularsap.kernels.succtree",
    "granularsap.kernels.sweep",
    "granularsap.kernels.triangles",
    "granularsap.mda.arith",
    "granularsap.search.frame",
]


def _dispatcher(obj):
    d = getattr(obj, "_dispatcher", obj)  # pjit's wrapper
    return d if isinstance(d, CPUDispatcher) else None


def _kernels(module):
    for name, obj in vars(module).items():
        d = _dispatcher(obj)
        if d is not None and d.py_func.__module__ == module.__name__:
            yield name, d


def _own_compile(module, name):
    """Whether ``name`` in ``module`` is a helper compiled on its own (not inlined)."""
    d = _dispatcher(module.__dict__.get(name))
    return d is not None and d.targetoptions.get("inline", "never") != "always"


def _prange_targets(tree):
    out = set()
    for node in ast.walk(tree):
        if (isinstance(node, ast.For) and isinstance(node.target, ast.Name)
                and isinstance(node.iter, ast.Call)
                and isinstance(node.iter.func, ast.Attribute)
                and node.iter.func.attr == "prange"):
            out.add(node.target.id)
    return out


def _constant_names(tree, module):
    """Names a kernel sees as literals: assigned a constant int or bool in it (numba
    types the variable as that literal), or module constants (frozen as literals)."""
    out = {name for name, v in vars(module).items()
           if isinstance(v, (bool, int)) and not name.startswith("__")}
    for node in ast.walk(tree):
        if (isinstance(node, ast.Assign) and isinstance(node.value, ast.Constant)
                and isinstance(node.value.value, (bool, int))):
            out.update(t.id for t in node.targets if isinstance(t, ast.Name))
    return out


def _offences(module):
    found = []
    for kname, d in _kernels(module):
        tree = ast.parse(textwrap.dedent(inspect.getsource(d.py_func)))
        prange = _prange_targets(tree)
        constant = _constant_names(tree, module)
        for node in ast.walk(tree):
            if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
                    and _own_compile(module, node.func.id)):
                continue
            for i, arg in enumerate(node.args):
                if isinstance(arg, ast.Constant) and isinstance(arg.value, (bool, int)):
                    found.append(f"{kname} -> {node.func.id}: argument {i} is the literal "
                                 f"{arg.value!r} (line {node.lineno})")
                elif isinstance(arg, ast.Name) and arg.id in constant:
                    found.append(f"{kname} -> {node.func.id}: argument {i} is {arg.id}, a "
                                 f"constant (line {node.lineno})")
                elif isinstance(arg, ast.Name) and arg.id in prange:
                    found.append(f"{kname} -> {node.func.id}: argument {i} is the prange "
                                 f"index {arg.id} (line {node.lineno})")
    return found


@pytest.mark.parametrize("name", MODULES)
def test_no_second_signature_from_a_call_site(name):
    module = importlib.import_module(name)
    assert list(_kernels(module)), f"{name} has no kernels: update MODULES"
    assert _offences(module) == []


def test_the_check_finds_both_mistakes(tmp_path):
    """The check itself, on a module written with both mistakes."""
    path = tmp_path / "signature_example.py"
    path.write_text(textwrap.dedent('''
        import numba

        from granularsap._numba import ijit, jit, pjit

        _LIMIT = 64

        @jit
        def helper(a, b):
            return a + b


        @ijit
        def inlined(a, b):
            return a - b


        @jit
        def kernel(x):
            w = 0
            return helper(0, x) + inlined(0, x) + helper(x, x) + helper(w, _LIMIT)


        @pjit
        def par(x, out):
            for c in numba.prange(x):
                out[c] = helper(c, x) + helper(x, numba.int64(c))
    '''))
    spec = importlib.util.spec_from_file_location("signature_example", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert sorted(_offences(module)) == [
        "kernel -> helper: argument 0 is the literal 0 (line 4)",
        "kernel -> helper: argument 0 is w, a constant (line 4)",
        "kernel -> helper: argument 1 is _LIMIT, a constant (line 4)",
        "par -> helper: argument 0 is the prange index c (line 4)"]


def test_every_module_with_kernels_is_checked():
    root = pathlib.Path(__file__).resolve().parent.parent
    with_kernels = sorted(
        ".".join(path.relative_to(root).with_suffix("").parts)
        for path in (root / "granularsap").rglob("*.py")
        if re.search(r"^@(p|i|h)?jit\b", path.read_text(), re.MULTILINE))
    assert with_kernels == sorted(MODULES)


# ----------------------------------------------- helpers without a Python entry


def _entryless(module):
    """Names of the kernels of ``module`` compiled without a CPython entry point
    (``hjit``): numba gives them none, and a call from Python crashes the process."""
    return {name for name, d in _kernels(module) if d.targetoptions.get("no_cpython_wrapper")}


def _is_kernel(fn):
    for d in fn.decorator_list:
        target = d.func if isinstance(d, ast.Call) else d
        name = target.attr if isinstance(target, ast.Attribute) else getattr(target, "id", "")
        if name.endswith("jit"):
            return True
    return False


def _python_calls(source, names):
    """(line, name, caller) of every call of one of ``names`` outside a kernel."""
    found = []

    def visit(node, fn):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                visit(child, child)
                continue
            if isinstance(child, ast.Call):
                f = child.func
                name = f.id if isinstance(f, ast.Name) else getattr(f, "attr", None)
                if name in names and (fn is None or not _is_kernel(fn)):
                    found.append((child.lineno, name, fn.name if fn else "<module>"))
            visit(child, fn)

    visit(ast.parse(source), None)
    return found


def test_helpers_without_an_entry_are_called_from_kernels_only():
    names = set()
    for name in MODULES:
        names |= _entryless(importlib.import_module(name))
    assert names, "no hjit helpers found: the check would pass on nothing"
    root = pathlib.Path(__file__).resolve().parent.parent
    paths = [p for folder in ("granularsap", "tests", "examples", "benchmarks")
             for p in (root / folder).rglob("*.py")]
    calls = [(str(p.relative_to(root)), *c) for p in paths
             for c in _python_calls(p.read_text(), names)]
    assert calls == []


def test_the_entry_check_finds_a_python_call():
    source = textwrap.dedent('''
        @hjit
        def helper(a):
            return a

        @jit
        def kernel(a):
            return helper(a)

        def wrapper(a):
            return kernels.helper(a) + kernel(a)
    ''')
    assert _python_calls(source, {"helper"}) == [(11, "helper", "wrapper")]
