"""Argument types shared by the subcommands: argparse ``type=`` callables and value lists.

Each takes the text of one command-line value and returns the value, or raises
``argparse.ArgumentTypeError`` (which argparse reports as a usage error, exit
code 2) or ``ValueError`` for the lists a subcommand reads itself.
"""

from __future__ import annotations

import argparse
import re

__all__ = ["axes", "frames", "nonneg", "parse_size", "positive_int", "split_list"]


def frames(text):
    """``START:STOP:STEP`` (any part may be empty) or one frame ``K`` -> ``slice``.

    Examples
    --------
    >>> frames("2:10:2"), frames("5"), frames("::3")
    (slice(2, 10, 2), slice(5, 6, None), slice(None, None, 3))
    """
    parts = text.split(":")
    if len(parts) > 3:
        raise argparse.ArgumentTypeError(f"expected START:STOP:STEP, got {text!r}") from None
    try:
        vals = [int(p) if p.strip() else None for p in parts] + [None] * (3 - len(parts))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected integers in START:STOP:STEP, got {text!r}") from None
    if len(parts) == 1 and vals[0] is not None:  # a single frame number
        vals = [vals[0], vals[0] + 1, None]
    start, stop, step = vals
    if (start is not None and start < 0) or (stop is not None and stop < 0):
        raise argparse.ArgumentTypeError(f"START and STOP must be >= 0, got {text!r}") from None
    if step is not None and step <= 0:
        raise argparse.ArgumentTypeError(f"STEP must be positive, got {text!r}") from None
    return slice(start, stop, step)


def axes(text):
    """Axis letters ``x``, ``y``, ``z`` (each once, any order) -> sorted axis numbers.

    Examples
    --------
    >>> axes("z"), axes("zx")
    ((2,), (0, 2))
    """
    letters = text.strip().lower()
    if not letters or any(c not in "xyz" for c in letters) or len(set(letters)) != len(letters):
        raise argparse.ArgumentTypeError(f"expected axis letters from x, y, z, each once (z for "
                                         f"a LAMMPS 2-D run), got {text!r}") from None
    return tuple(sorted("xyz".index(c) for c in letters))


def nonneg(text):
    """A finite number >= 0 (a cutoff, a radius, a skin, seconds)."""
    try:
        val = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not val >= 0 or val == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a finite number >= 0, got {text!r}") from None
    return val


def positive_int(text):
    """An integer >= 1 (threads, workers, particles)."""
    try:
        val = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if val <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    return val


def parse_size(text):
    """``"1e5"``, ``"2^18"``, ``"2**18"``, ``"100k"``, ``"1M"`` or ``"12345"`` -> int.

    Examples
    --------
    >>> [parse_size(t) for t in ("1e5", "2^18", "100k", "1M", "12345")]
    [100000, 262144, 100000, 1000000, 12345]
    """
    t = text.strip().lower().replace("_", "")
    m = re.fullmatch(r"(\d+)\s*(?:\^|\*\*)\s*(\d+)", t)
    if m:
        return int(m.group(1)) ** int(m.group(2))
    mult = {"k": 10**3, "m": 10**6}
    if t and t[-1] in mult:
        return int(round(float(t[:-1]) * mult[t[-1]]))
    try:
        value = float(t)
    except ValueError:
        raise ValueError(f"cannot read size {text!r}; use e.g. 10000, 1e5, 2^18 or 100k") \
            from None
    if value < 1 or value != int(value):
        raise ValueError(f"size must be a positive whole number, got {text!r}")
    return int(value)


def split_list(values):
    """The items of values given space or comma separated (``--sizes 1e4,1e5 1e6``).

    Examples
    --------
    >>> split_list(["1e4,1e5", "1e6"]), split_list(None)
    (['1e4', '1e5', '1e6'], [])
    """
    out = []
    for v in values or []:
        out.extend(x for x in re.split(r"[,\s]+", v) if x)
    return out
