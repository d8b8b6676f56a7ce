"""Side-by-side benchmarks of granularsap against other neighbour searches.

``granularsap bench`` runs the same deterministic inputs (:mod:`.workloads`)
through granularsap and every installed peer library (:mod:`.peers`), checks
that all found the same pairs, and reports timings, memory, JSON and plots
(:mod:`.harness`, :mod:`.report`, :mod:`.runner`).  The command line is in
:mod:`granularsap.cli.bench`; the plain numba cell list peer in
:mod:`.celllist`.  Reference: docs/bench.md.
"""
