"""``granularsap bench paper``: the experiments of Capannini & Larsson, here.

Section 6: ``n`` boxes with sides varying per axis move freely in a world
cube of density ``d`` (total box volume over world volume), pass through each
other and bounce on the walls; the engine runs every frame (100 by default).
Section 7: ball clustering (boxes fly to the centre of a ball and through it)
and plane clustering (boxes on a grid in two coordinates cross the plane
``u = 0`` together), the latter with and without dynamic axis swapping.

For every run it reports per-phase seconds (sort, candidates, pairing) of
the steady state (frames after the first, buffers reused), the fresh
single call (``box_overlaps``), pairs per frame, the dispersion D of the
sort buckets per frame, the speedup of the threads over one thread of the
same code and over the sequential Algorithm 1, and the engine's working
memory.  Every frame's answer is checked against a second path (Algorithm 1
or one thread) on the frames where both run.
"""

from __future__ import annotations

import json
import math
import platform
import re
import resource
import time

import numba
import numpy as np

from .. import SweepAndPrune, box_overlaps

DENSITIES = (0.05, 0.15, 0.25, 0.35)
SIZES = (1 << 18, 1 << 19, 1 << 20)


def _parse_size(text):
    text = str(text).strip().lower().replace("_", "")
    m = re.fullmatch(r"(\d+)\^(\d+)", text)
    if m:
        return int(m.group(1)) ** int(m.group(2))
    mult = 1
    if text.endswith("k"):
        text, mult = text[:-1], 1000
    elif text.endswith("m"):
        text, mult = text[:-1], 1000000
    value = float(text) * mult
    if value < 1 or not value.is_integer():
        raise ValueError(f"--sizes: {text!r} is not a positive whole number")
    return int(value)


def _listed(values, parse):
    out = []
    for v in values or []:
        out.extend(parse(x) for x in re.split(r"[,\s]+", str(v)) if x)
    return out


# ---------------------------------------------------------------- scenarios

class UniformBoxes:
    """Section 6: uniform boxes with per-axis sides, bouncing in the unit cube."""

    def __init__(self, n, density, seed=0, speed=0.05):
        rng = np.random.default_rng(seed)
        s = (density / n) ** (1.0 / 3.0)
        size = s * (0.5 + rng.random((n, 3)))
        size *= s / np.cbrt(np.mean(np.prod(size, axis=1)))
        self.size = size
        self.lower = rng.random((n, 3)) * (1.0 - size)
        direction = rng.normal(size=(n, 3))
        direction /= np.linalg.norm(direction, axis=1)[:, None]
        self.vel = direction * (speed * s)  # a twentieth of a box side per frame

    def frame(self):
        return self.lower, self.lower + self.size

    def step(self):
        self.lower += self.vel
        low = self.lower < 0.0
        high = self.lower + self.size > 1.0
        self.vel[low | high] *= -1.0
        np.clip(self.lower, 0.0, 1.0 - self.size, out=self.lower)


class BallCluster:
    """Section 7, Figure 5: boxes converge on the centre of a ball, then spread.

    The paper lets a collision response stop boxes from passing through each
    other; here every box moves radially so that the ball shrinks until its
    density reaches ``peak`` (a dense, barely interpenetrating cluster) in the
    middle of the run and then expands back.
    """

    def __init__(self, n, frames, seed=0, density=0.05, peak=0.4):
        rng = np.random.default_rng(seed)
        r = np.cbrt(rng.random(n))
        d = rng.normal(size=(n, 3))
        d /= np.linalg.norm(d, axis=1)[:, None]
        self.offset = 0.5 * r[:, None] * d
        ball = 4.0 / 3.0 * math.pi * 0.5 ** 3
        s = (density * ball / n) ** (1.0 / 3.0)
        self.half = 0.5 * s * (0.5 + rng.random((n, 3)))
        self.squeeze = 1.0 - (density / peak) ** (1.0 / 3.0)
        self.frames = frames
        self.t = 0

    def frame(self):
        phase = 1.0 - abs(2.0 * self.t / max(self.frames - 1, 1) - 1.0)
        centre = 0.5 + self.offset * (1.0 - self.squeeze * phase)
        return centre - self.half, centre + self.half

    def step(self):
        self.t += 1


class PlaneCluster:
    """Section 7, Figure 6: a grid in two coordinates crosses the plane u = 0.

    ``side`` x ``side`` equal cubes; their centres sit on a regular grid in the
    two other coordinates and uniformly above and below the plane in ``u``;
    all reach the plane in the middle of the run, where neighbours almost
    touch.  Collision free throughout.
    """

    def __init__(self, side, frames, u_axis, seed=0):
        rng = np.random.default_rng(seed)
        n = side * side
        g = (np.arange(side) + 0.5) / side
        a, b = np.meshgrid(g, g, indexing="ij")
        others = [ax for ax in range(3) if ax != u_axis]
        self.centre = np.empty((n, 3))
        self.centre[:, others[0]] = a.ravel()
        self.centre[:, others[1]] = b.ravel()
        self.centre[:, u_axis] = rng.uniform(-0.5, 0.5, n)
        self.half = 0.49 / side
        self.vel = np.zeros((n, 3))
        self.vel[:, u_axis] = -self.centre[:, u_axis] / (0.5 * frames)

    def frame(self):
        return self.centre - self.half, self.centre + self.half

    def step(self):
        self.centre += self.vel


# ---------------------------------------------------------------- runner

def _phases(stats):
    sec = stats["seconds"]
    return {k: sec[k] for k in ("sort", "candidates", "pairing", "total")}


def run_scenario(scene, frames, threads, check_every=0, progress=None, label=""):
    """Run the engine over ``frames`` frames; returns per-frame records."""
    engine = SweepAndPrune(n_threads=threads)
    return _drive(engine, scene, frames, threads, check_every, progress, label)


def _drive(engine, scene, frames, threads, check_every, progress, label):
    records = []
    for f in range(frames):
        lower, upper = scene.frame()
        t0 = time.perf_counter()
        pairs = engine.update(lower, upper)
        wall = time.perf_counter() - t0
        st = engine.stats
        rec = {"frame": f, "wall": wall, **_phases(st), "pairs": len(pairs),
               "tested": st["candidates_tested"], "axes": list(st["axes"]),
               "dispersion": {str(k): v for k, v in st["dispersion"].items()},
               "swaps": st["swaps"], "path": st.get("path")}
        if check_every and f % check_every == 0:
            ref = SweepAndPrune(path="parallel", n_threads=1).update(lower, upper)
            rec["checked"] = bool(len(ref) == len(pairs) and np.array_equal(
                _canon(ref), _canon(pairs)))
            if not rec["checked"]:
                raise AssertionError(f"{label}: frame {f}: parallel and one-thread answers "
                                     "differ")
        records.append(rec)
        if progress and (f % max(1, frames // 10) == 0 or f == frames - 1):
            progress(f"  {label} frame {f + 1}/{frames}: {wall * 1e3:.0f} ms, "
                     f"{len(pairs)} pairs")
        scene.step()
    return records, engine


def _paths(records):
    """``"columns 9, parallel 1"``: the engine's path per frame, counted."""
    counts = {}
    for r in records:
        counts[r.get("path")] = counts.get(r.get("path"), 0) + 1
    return ", ".join(f"{p} {c}" for p, c in sorted(counts.items(), key=lambda x: -x[1]))


def _canon(pairs):
    key = pairs[:, 0].astype(np.int64) * (int(pairs.max(initial=0)) + 1) + pairs[:, 1]
    return np.sort(key)


def _steady(records):
    rest = records[1:] if len(records) > 1 else records
    return {k: float(np.median([r[k] for r in rest]))
            for k in ("sort", "candidates", "pairing", "total", "wall")}


def _time_fresh(lower, upper, threads):
    t0 = time.perf_counter()
    box_overlaps(lower, upper, n_threads=threads)
    return time.perf_counter() - t0


def _time_path(lower, upper, path, threads, repeats=1):
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        SweepAndPrune(path=path, n_threads=threads).update(lower, upper)
        best = min(best, time.perf_counter() - t0)
    return best


def uniform_experiment(n, density, frames, threads, seed, progress, sequential=True):
    scene = UniformBoxes(n, density, seed=seed)
    lower, upper = scene.frame()
    # warm the JIT for this process outside the timings
    box_overlaps(lower[:2048], upper[:2048], n_threads=threads)
    fresh = _time_fresh(lower, upper, threads)
    # warm every path (JIT, first-touch) outside the timings
    SweepAndPrune(path="sequential", n_threads=1).update(lower[:5000], upper[:5000])
    SweepAndPrune(path="parallel", n_threads=1).update(lower[:5000], upper[:5000])
    records, engine = run_scenario(scene, frames, threads, check_every=max(1, frames // 4),
                                   progress=progress, label=f"n={n} d={density}")
    steady = _steady(records)
    # the same code on one thread, a few frames, for the parallel speedup
    one_scene = UniformBoxes(n, density, seed=seed)
    one, _ = run_scenario(one_scene, min(frames, 4), 1)
    one_steady = _steady(one)
    out = {"n": n, "density": density, "frames": frames, "threads": threads,
           "fresh_seconds": fresh, "steady": steady, "one_thread": one_steady,
           "pairs_per_frame": float(np.mean([r["pairs"] for r in records])),
           "tested_per_frame": float(np.mean([r["tested"] for r in records])),
           "dispersion_after_first": max(
               (max(r["dispersion"].values()) for r in records[1:]), default=0.0),
           "engine_bytes_per_box": engine.nbytes / n,
           "staging_bytes_per_box": engine.staging_nbytes / n,
           "paths": _paths(records), "per_frame": records}
    out["speedup_threads"] = one_steady["total"] / steady["total"]
    out["speedup_pairing"] = one_steady["pairing"] / max(steady["pairing"], 1e-12)
    if sequential:
        lower, upper = UniformBoxes(n, density, seed=seed).frame()
        seq = _time_path(lower, upper, "sequential", 1)
        out["sequential_seconds"] = seq
        out["speedup_vs_sequential"] = seq / steady["total"]
    return out


def clustering_experiment(kind, n, frames, threads, seed, progress):
    runs = {}
    if kind == "ball":
        scene = BallCluster(n, frames, seed=seed)
        rec, _ = run_scenario(scene, frames, threads, check_every=max(1, frames // 5),
                              progress=progress, label="ball")
        runs["ball"] = rec
    else:
        side = max(2, int(round(math.sqrt(n))))
        for u in (0, 1):
            for swap, shards in ((True, True), (False, True), (True, False), (False, False)):
                scene = PlaneCluster(side, frames, u, seed=seed)
                engine = SweepAndPrune(axes="auto" if swap else (0, 1), n_threads=threads)
                if not shards:
                    engine.max_bins = 1  # the paper's Algorithm 4 exactly
                label = (f"plane u={'xy'[u]} {'swap' if swap else 'fixed'}"
                         f"{'' if shards else ' paper'}")
                rec, _ = _drive(engine, scene, frames, threads, max(1, frames // 5),
                                progress, label)
                runs[label] = rec
    summary = {}
    for label, rec in runs.items():
        walls = np.array([r["total"] for r in rec])
        third = max(1, frames // 3)
        before = float(np.median(walls[1:third])) if third > 1 else float(walls[0])
        mid = slice(int(frames * 0.45), int(frames * 0.55) + 1)
        during = float(np.median(walls[mid]))
        swaps = [r["frame"] for i, r in enumerate(rec) if i and r["swaps"] > rec[i - 1]["swaps"]]
        summary[label] = {"before": before, "during": during, "ratio": during / before,
                          "swap_frames": swaps, "pairs_max": max(r["pairs"] for r in rec),
                          "paths": _paths(rec), "per_frame": rec}
    return summary


# ---------------------------------------------------------------- output

def _machine():
    import numba

    info = {"python": platform.python_version(), "numpy": np.__version__,
            "numba": numba.__version__, "machine": platform.machine(),
            "cores": numba.config.NUMBA_NUM_THREADS}
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    info["cpu"] = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return info


def _plot(results, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    uni = results["uniform"]
    sizes = sorted({r["n"] for r in uni})
    clusters = results.get("clustering", {})
    ncols = len(sizes) + (1 if clusters else 0)
    fig, axes = plt.subplots(1, ncols, figsize=(4.2 * ncols, 3.8), squeeze=False)
    for ax, n in zip(axes[0], sizes, strict=False):
        rows = sorted((r for r in uni if r["n"] == n), key=lambda r: r["density"])
        d = [r["density"] for r in rows]
        sort = np.array([r["steady"]["sort"] for r in rows]) * 1e3
        cand = np.array([r["steady"]["candidates"] for r in rows]) * 1e3
        pair = np.array([r["steady"]["pairing"] for r in rows]) * 1e3
        if len(d) == 1:
            ax.bar(["sort", "cand.", "pairing"], [sort[0], cand[0], pair[0]],
                   color=["0.35", "0.55", "0.8"])
            ax.set_title(f"n = {n}, d = {d[0]}")
        else:
            ax.stackplot(d, sort, cand, pair, labels=["sorting", "candidates", "pairing"],
                         colors=["0.35", "0.55", "0.8"])
            for x, r, top in zip(d, rows, sort + cand + pair, strict=True):
                ax.annotate(f"{r['speedup_threads']:.1f}x", (x, top), ha="center",
                            va="bottom", fontsize=8)
            ax.set_xlabel("density d")
            ax.set_title(f"n = {n}")
        ax.set_ylabel("ms per frame (steady state)")
    if axes[0][0].get_legend_handles_labels()[0]:
        axes[0][0].legend(loc="upper left", fontsize=8)
    if clusters:
        ax = axes[0][-1]
        for label, s in clusters.items():
            t = [r["total"] * 1e3 for r in s["per_frame"]]
            ax.plot(t, label=label, lw=1)
        ax.set_xlabel("frame")
        ax.set_ylabel("ms per frame")
        ax.set_title("clustering")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run_paper(args):
    """Entry point of ``granularsap bench paper``; returns an exit code."""
    quick = bool(getattr(args, "quick", False))
    threads = getattr(args, "threads", None) or numba.config.NUMBA_NUM_THREADS
    sizes = _listed(getattr(args, "sizes", None), _parse_size) or (
        [1 << 14, 1 << 15] if quick else list(SIZES))
    densities = _listed(getattr(args, "density", None), float) or (
        [0.05, 0.35] if quick else list(DENSITIES))
    frames = getattr(args, "frames", None) or (10 if quick else 100)
    cl_frames = getattr(args, "frames", None) or (40 if quick else 100)
    seed = getattr(args, "seed", 0) or 0
    json_path = getattr(args, "json", None) or "bench-paper.json"
    plot_path = getattr(args, "plot", None) or "bench-paper.png"

    def progress(msg):
        print(msg, flush=True)

    print(f"granularsap bench paper: sizes {sizes}, densities {densities}, {frames} frames, "
          f"{threads} threads", flush=True)
    results = {"machine": _machine(), "threads": threads, "frames": frames, "uniform": []}
    header = (f"{'n':>8} {'d':>5} {'sort':>7} {'cand':>7} {'pair':>7} {'total':>7} "
              f"{'fresh':>7} {'pairs/frame':>12} {'D max':>7} {'x1thr':>6} {'xpair':>6} "
              f"{'xAlg1':>6} {'B/box':>6}  path (frames)")
    rows = []
    for n in sizes:
        for d in densities:
            r = uniform_experiment(n, d, frames, threads, seed, progress,
                                   sequential=n <= (1 << 20))
            results["uniform"].append(r)
            s = r["steady"]
            rows.append(f"{n:>8} {d:>5.2f} {s['sort'] * 1e3:>7.1f} "
                        f"{s['candidates'] * 1e3:>7.1f} {s['pairing'] * 1e3:>7.1f} "
                        f"{s['total'] * 1e3:>7.1f} {r['fresh_seconds'] * 1e3:>7.1f} "
                        f"{r['pairs_per_frame']:>12.0f} {r['dispersion_after_first']:>7.4f} "
                        f"{r['speedup_threads']:>6.2f} {r['speedup_pairing']:>6.2f} "
                        f"{r.get('speedup_vs_sequential', float('nan')):>6.1f} "
                        f"{r['engine_bytes_per_box']:>6.0f}")
            rows[-1] += f"  {r['paths']}"
            print(header + "\n" + rows[-1], flush=True)
    cl_n = 1 << 14 if quick else 1 << 19
    pl_side = 128 if quick else 750
    results["clustering"] = {}
    results["clustering"].update(clustering_experiment("ball", cl_n, cl_frames, threads, seed,
                                                       progress))
    results["clustering"].update(clustering_experiment("plane", pl_side ** 2, cl_frames,
                                                       threads, seed, progress))
    print("\nUniform boxes, steady state, milliseconds per frame "
          f"({threads} threads; x1thr: speedup over one thread of the same code; xpair: the "
          "same for the pairing phase; xAlg1: over the sequential Algorithm 1; B/box: engine "
          "working memory; path: how many frames took each path, SweepAndPrune(path='auto'))")
    print(header)
    for row in rows:
        print(row)
    print("\nClustering (total ms per frame, median; 'paper': one shard, the paper's "
          "Algorithm 4 exactly)")
    print(f"{'scenario':<26} {'before':>8} {'during':>8} {'ratio':>6}  swaps at frames; "
          "paths (frames)")
    for label, s in results["clustering"].items():
        print(f"{label:<26} {s['before'] * 1e3:>8.1f} {s['during'] * 1e3:>8.1f} "
              f"{s['ratio']:>6.2f}  {s['swap_frames'][:5]}; {s['paths']}")
    results["peak_rss_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    with open(json_path, "w") as fh:
        json.dump(results, fh, indent=1)
    _plot(results, plot_path)
    print(f"\nwrote {json_path} and {plot_path}; peak RSS {results['peak_rss_mib']:.0f} MiB")
    return 0
