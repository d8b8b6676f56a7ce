"""Every command and snippet in README.md and docs/*.md runs as written, twice in a row.

What runs
---------
Every fenced block whose info string starts with ``python``, ``sh``, ``bash``,
``shell`` or ``console``, file by file, in the order of the file, in one
temporary copy of the clone (its tracked files, outputs land there), twice in
a row in the same copy (the second run meets the outputs of the first, as a
user who runs a command again does):

* ``python`` blocks run in one interpreter per file (a block may use the names
  an earlier block of the same file defined), as a ``__main__`` script;
  a block written as a doctest (``>>>`` lines) is run as one and its output is
  checked;
* ``sh`` / ``bash`` / ``shell`` blocks run with ``bash -e -o pipefail``; in a
  ``console`` block the lines starting with ``$ `` are the commands (the others
  are output, not checked).

The copy leaves out the packages ``granularsap/`` and ``lammps_bridge/``:
they are imported from this clone itself (``PYTHONPATH``), so numba's compile
cache next to them, warm from the rest of the suite, serves the copy too.

Substitutions (documented here, applied to shell lines; nothing else changes)
-----------------------------------------------------------------------------
:data:`SUBSTITUTIONS`: ``pip install ...`` and ``python -m pytest ...`` are not
run (the suite runs in the environment it was installed into, and it is the
suite); ``export NUMBA_CACHE_DIR=...`` is not run (an empty cache would make
every later command compile for a minute); ``ruff check .`` checks this
clone (the copy has no packages); every ``granularsap bench`` command runs
with tiny sizes and granularsap's own peers only (``--quick --sizes 1000
--repeats 1 --frames 2 --peers granularsap,granularsap-steady``, its other
options as written): the figures it prints are not the documented ones, the
command line is.

Blocks that must not run
------------------------
A block that cannot run here (it needs a cluster or a scheduler address, or it
is a measurement that takes minutes) says so in its info string:
````` ```python no-run: <reason> `````  (GitHub shows it as Python).
:data:`NO_RUN` lists every such block by file and reason; a new one fails
:func:`test_no_run_blocks_are_few_and_justified` until it is listed there,
and they must stay a small share of the blocks.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
import textwrap
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
RUN_LANGS = {"python", "sh", "bash", "shell", "console"}
#: left out of the copy: imported from this clone (see the module docstring)
PACKAGES = ("granularsap", "lammps_bridge")

#: (pattern, replacement, why) applied to every shell line, in this order
SUBSTITUTIONS = [
    (r"\bpip install\b[^&|;#\n]*", ": ",
     "pip install: the suite runs in the environment it was installed into"),
    (r"\bpython -m pytest\b[^&|;#\n]*", ": ", "the test suite: this test is part of it"),
    (r"^\s*export NUMBA_CACHE_DIR=[^#\n]*", ": ",
     "an empty numba cache: every later command would compile for a minute"),
    (r"\bruff check \.", f"ruff check {shlex.quote(str(ROOT))}",
     "the copy has no packages: ruff checks this clone"),
]
#: what every `granularsap bench` command gets instead of its sizes, repeats and peers
BENCH_TINY = ["--quick", "--sizes", "1000", "--repeats", "1", "--frames", "2",
              "--max-seconds", "30", "--peers", "granularsap,granularsap-steady"]
_BENCH_VALUED = {"--sizes": "+", "--repeats": 1, "--frames": 1, "--peers": 1,
                 "--exclude": 1, "--max-seconds": 1}

#: every ``no-run`` block: (file, reason); see the module docstring
NO_RUN = {
    ("docs/boxes.md", "a measurement of minutes: 2^20 boxes, ten scenes, three paths"),
    ("docs/dask.md", "a measurement of minutes and 10 GiB: 1e7 atoms on a 2-worker cluster"),
    ("docs/dropins.md", "a measurement of minutes: three threading layers, seven repeats each"),
}
#: no more than this share of the runnable blocks may be ``no-run``
MAX_NO_RUN_SHARE = 0.1


@dataclass
class Block:
    file: str      # relative to the clone
    line: int      # of the opening fence
    lang: str
    reason: str | None  # the no-run reason, None for a block that runs
    text: str

    @property
    def where(self):
        return f"{self.file}:{self.line}"


def doc_files():
    return ["README.md"] + sorted(f"docs/{p.name}" for p in (ROOT / "docs").glob("*.md"))


def blocks(path, text=None):
    """Every fenced block of ``path`` (relative to the clone; or of ``text``)."""
    text = (ROOT / path).read_text() if text is None else text
    out, lines = [], text.split("\n")
    k = 0
    while k < len(lines):
        m = re.match(r"^(\s*)(`{3,}|~{3,})\s*(.*)$", lines[k])
        if not m:
            k += 1
            continue
        indent, fence, info = m.groups()
        body, start = [], k + 1
        k += 1
        while k < len(lines) and not re.match(rf"^\s*{re.escape(fence)}\s*$", lines[k]):
            body.append(lines[k][len(indent):] if lines[k].startswith(indent) else lines[k])
            k += 1
        k += 1
        words = info.split(None, 1)
        lang = words[0].lower() if words else ""
        rest = words[1] if len(words) > 1 else ""
        reason = None
        mark = re.match(r"no-run\s*:?\s*(.*)$", rest)
        if mark:
            reason = mark.group(1).strip()
        out.append(Block(path, start, lang, reason, "\n".join(body) + "\n"))
    return out


def all_blocks():
    return [b for f in doc_files() for b in blocks(f)]


def _bench(line):
    """A `granularsap bench ...` line with tiny sizes (see BENCH_TINY)."""
    code, _, comment = line.partition(" #")
    words = shlex.split(code)
    k = words.index("bench") + 1
    if "--list" in words:
        return line
    kept = words[:k]
    while k < len(words):
        w = words[k]
        if w in _BENCH_VALUED:
            k += 1
            if _BENCH_VALUED[w] == "+":
                while k < len(words) and not words[k].startswith("-"):
                    k += 1
            else:
                k += 1
            continue
        if w == "--quick":
            k += 1
            continue
        kept.append(w)
        k += 1
    return shlex.join(kept + BENCH_TINY)


def shell_script(block):
    """The commands a shell block runs, after :data:`SUBSTITUTIONS`."""
    text = block.text
    if block.lang == "console":
        cmds, cont = [], False
        for line in text.split("\n"):
            if line.startswith("$ ") or cont:
                cmds.append(line[2:] if line.startswith("$ ") else line)
                cont = line.endswith("\\")
        text = "\n".join(cmds) + "\n"
    out = []
    for line in text.split("\n"):
        for pattern, repl, _ in SUBSTITUTIONS:
            line = re.sub(pattern, repl, line)
        if re.match(r"^\s*(time\s+)?granularsap bench\b", line):
            line = _bench(line)
        out.append(line)
    return "\n".join(out)


DRIVER = '''
import doctest, os, subprocess, sys, traceback

def run(blocks):
    ns = {"__name__": "__main__", "__file__": "snippet.py"}
    for where, lang, text in blocks:
        print(f"::: {where} ({lang})", flush=True)
        if lang == "python":
            if text.lstrip().startswith(">>>"):
                test = doctest.DocTestParser().get_doctest(text, ns, where, where, 0)
                runner = doctest.DocTestRunner(
                    optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
                runner.run(test, clear_globs=False)
                ns.update(test.globs)  # the doctest ran on a copy of the names
                if runner.failures:
                    sys.exit(f"{where}: {runner.failures} doctest example(s) failed")
            else:
                try:
                    exec(compile(text, where, "exec"), ns)
                except BaseException:
                    traceback.print_exc()
                    sys.exit(f"{where}: the python block raised")
        else:
            proc = subprocess.run(["bash", "-e", "-o", "pipefail", "-c", text])
            if proc.returncode:
                sys.exit(f"{where}: the {lang} block exited {proc.returncode}")

if __name__ == "__main__":
    run(BLOCKS)
'''


@pytest.fixture(scope="module")
def clone(tmp_path_factory):
    """A copy of the clone's tracked files, without the packages (see the docstring)."""
    dest = tmp_path_factory.mktemp("clone")
    try:
        files = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard"],
                               cwd=ROOT, capture_output=True, text=True, check=True).stdout
        names = [n for n in files.splitlines() if n]
    except (OSError, subprocess.CalledProcessError):  # not a git checkout
        names = [str(p.relative_to(ROOT)) for p in ROOT.rglob("*") if p.is_file()
                 and not {".git", ".venv", "__pycache__"} & set(p.relative_to(ROOT).parts)]
    for name in names:
        if name.split("/")[0] in PACKAGES or not (ROOT / name).is_file():
            continue
        (dest / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / name, dest / name)
    return dest


def _env():
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])]), MPLBACKEND="Agg")
    env.pop("PYTHONWARNINGS", None)
    return env


def runnable(path):
    return [b for b in blocks(path) if b.lang in RUN_LANGS and b.reason is None]


FILES_WITH_BLOCKS = [f for f in doc_files() if runnable(f)]


@pytest.mark.slow
@pytest.mark.parametrize("path", FILES_WITH_BLOCKS)
def test_blocks_run_as_written_twice(path, clone):
    todo = [(b.where, "python" if b.lang == "python" else "sh",
             b.text if b.lang == "python" else shell_script(b)) for b in runnable(path)]
    script = clone / f"_run_{Path(path).stem}.py"
    script.write_text(DRIVER.replace("BLOCKS)", f"{todo!r})"))
    for attempt in ("first run", "second run"):
        proc = subprocess.run([sys.executable, str(script)], cwd=clone, env=_env(),
                              capture_output=True, text=True, timeout=1800)
        assert proc.returncode == 0, (
            f"{path}, {attempt}: {proc.stderr.strip().splitlines()[-1:]}\n"
            f"--- stdout (tail)\n{proc.stdout[-3000:]}\n--- stderr (tail)\n{proc.stderr[-5000:]}")


def test_no_run_blocks_are_few_and_justified():
    every = [b for b in all_blocks() if b.lang in RUN_LANGS]
    marked = [b for b in every if b.reason is not None]
    for b in marked:
        assert len(b.reason.split()) >= 3, f"{b.where}: a no-run block says why in a few words"
    found = {(b.file, b.reason) for b in marked}
    assert found <= NO_RUN, ("no-run blocks not listed in NO_RUN (run them, or list them with "
                             f"their reason): {sorted(found - NO_RUN)}")
    assert len(marked) <= max(3, MAX_NO_RUN_SHARE * len(every)), [b.where for b in marked]
    # listed ones that disappeared: keep the list honest
    assert NO_RUN <= found, f"NO_RUN lists blocks no longer there: {sorted(NO_RUN - found)}"


def test_command_blocks_are_tagged():
    """A fenced block that shows commands says in its info string whether it runs:
    sh/console/python run here, text (or any other tag) is only shown."""
    for b in all_blocks():
        if b.lang:
            continue
        first = b.text.lstrip().split("\n")[0]
        assert not re.match(r"(\$ |granularsap |python |pip |>>> )", first), (
            f"{b.where}: untagged block starting {first[:40]!r}: tag it sh, console or "
            "python to run it, text to only show it")


def test_the_parser_and_substitutions():
    """What the runner does to a block (so that what this test runs is what it says)."""
    b = Block("x.md", 1, "sh", None, textwrap.dedent("""\
        pip install -e ".[all]" && granularsap contacts a.dump -o a.h5   # quick
        export NUMBA_CACHE_DIR=$(mktemp -d)
        granularsap bench md-liquid --sizes 1e5 1e6 --peers lammps,vesin --json b.json
        granularsap bench --list
    """))
    lines = shell_script(b).split("\n")
    assert lines[0] == ": && granularsap contacts a.dump -o a.h5   # quick"
    assert lines[1] == ": "
    assert lines[2] == shlex.join(["granularsap", "bench", "md-liquid", "--json", "b.json",
                                   *BENCH_TINY])
    assert lines[3] == "granularsap bench --list"
    c = Block("x.md", 1, "console", None, "$ granularsap info a.h5 \\\n  --json\noutput\n")
    assert shell_script(c) == "granularsap info a.h5 \\\n  --json\n"
    sample = textwrap.dedent("""\
        text
        ```python no-run: needs a scheduler address
        client = Client("tcp://scheduler:8786")
        ```
        1. a list item:

           ```sh
           granularsap info a.h5
           ```
        ````text
        ```
        ````
    """)
    got = [(b.line, b.lang, b.reason, b.text) for b in blocks("x.md", sample)]
    assert got == [(2, "python", "needs a scheduler address",
                    'client = Client("tcp://scheduler:8786")\n'),
                   (7, "sh", None, "granularsap info a.h5\n"),
                   (10, "text", None, "```\n")]
