"""The chooser: which candidate builder a build takes, the column sweep
(``"columns"``) or the paper's Sweep and Prune (``"sweep"``), decided from the
frame alone (candidates per pair predicted by the column plan, the particle
count, the images asked for, the coordinates), never from a timing: the same
frame gets the same path in every process, with any thread count.  Each choice
comes with the sentence ``stats["path_reason"]`` shows."""

from __future__ import annotations

#: the values of ``path=``
PATHS = ("auto", "columns", "sweep")
#: ``path="auto"`` takes the paper's sweep where the column plan predicts more
#: candidates per pair and per particle than these, on at least SWEEP_MIN_N
#: particles (measured: docs/engine.md, "Two paths, chosen per build")
SWEEP_CPP = 1000.0
SWEEP_PER_PARTICLE = 200.0
SWEEP_MIN_N = 50000


def choose_path(path, n, minimum, cpp, far, far_ranges):
    """(path, reason) of a build: ``path`` when forced, else chosen from the frame.

    ``cpp`` is ``plan.predict_cpp``'s (candidates per pair, per particle) of the
    column plan.  The paper's sweep tests a few candidates per pair whatever
    the size spread but pays several times more per particle (its sort and
    ghost cubes), so it is taken only where the column sweep is predicted to
    test very many candidates per pair and per particle on a large frame (the
    measurements are in docs/engine.md).  ``far``: coordinates lie more than
    ``far_ranges`` ranges away along an open axis, where the paper's sweep
    would widen every cube by their rounding (and, with periodic axes, make
    every particle a ghost of many cells): the column sweep, whatever was
    asked."""
    chosen, reason = _choose(path, n, minimum, cpp)
    if chosen == "sweep" and far:
        return "columns", (f"{reason}; but coordinates lie more than {far_ranges:.3g} ranges "
                           "away along an open axis, where the paper's sweep would widen "
                           "every cube by their rounding: the column sweep")
    return chosen, reason


def _choose(path, n, minimum, cpp):
    if path != "auto":
        return path, f"path={path!r} given"
    if not minimum:
        return "columns", "every periodic image asked for: the column sweep wraps its stencil"
    per_pair, per_particle = cpp
    figures = (f"the column plan predicts {per_pair:.1f} candidates per pair "
               f"({per_particle:.1f} per particle) on {n} particles")
    limits = f"{SWEEP_CPP:g} per pair and {SWEEP_PER_PARTICLE:g} per particle"
    if n < SWEEP_MIN_N:
        return "columns", f"{figures}: below {SWEEP_MIN_N} particles, the column sweep"
    if per_pair > SWEEP_CPP and per_particle > SWEEP_PER_PARTICLE:
        return "sweep", f"{figures}: above {limits}, the paper's sweep"
    return "columns", f"{figures}: not above {limits}, the column sweep"


def small_frame_reason(path, n):
    """The reason of a small frame (``engine.SearchEngine._small``), which always
    takes the column sweep."""
    if path != "auto":
        return f"path={path!r} given"
    return (f"{n} particles: the column sweep (the paper's sweep is considered from "
            f"{SWEEP_MIN_N} particles)")
