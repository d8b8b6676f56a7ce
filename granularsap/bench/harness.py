"""Run workloads through peers: warm-up, timing, peak memory, agreement.

Protocol for one workload and one peer:

1. ``setup`` (untimed: stateful peers build their engine here);
2. one warm-up run on frame 0, untimed (numba compiles, caches fill); its
   pairs are kept for the agreement check;
3. the fresh call, for stateful peers only: ``close`` and ``setup`` again
   (new engine, new memory), then one timed run on frame 0; its pairs must
   equal the warm-up's;
4. the steady state: ``repeats`` timed runs of frame 0 for a single-frame
   workload, or one run per remaining frame for a trajectory (a stateful
   peer carries its state from the fresh call on).  Each run measures wall
   seconds (``time.perf_counter``), process CPU seconds
   (``time.process_time``, all threads) and the peak resident memory above
   the RSS at its start (Linux: the kernel's high-water mark ``VmHWM``,
   reset through ``/proc/self/clear_refs`` before each run; elsewhere not
   measured).  A peer that times itself (:meth:`Peer.last_seconds`, LAMMPS's
   own timers) reports that figure instead of the wall seconds, and no CPU
   seconds;
5. the median over the steady runs is reported (``seconds``) and their
   minimum (``min_seconds``), with the fresh call beside it
   (``fresh_seconds``) and, when the peer's stats have ``candidates_tested``
   and ``pairs``, the candidates tested per pair found.  With ``small_runs``
   (the CLI gives :data:`SMALL_RUNS`) a single-frame workload whose runs take
   less than :data:`SMALL_SECONDS` is run again until it has that many steady
   runs or :data:`SMALL_BUDGET` more seconds have passed: the minimum of a
   small frame is then a per-step figure over many steps, as a time-stepping
   loop sees it.  These added runs repeat the frame whose peak memory the
   planned runs measured, and measure none: resetting the high-water mark and
   reading it back slows the small run that follows by about a tenth (0.174
   against 0.197 ms per ``ContactSearch.update`` of 1,000 polydisperse
   spheres, measured), which would weigh on the peers timed by the wall clock
   and not on those that time themselves.

Agreement: every peer's pairs are reduced to a signature (the pair count of
every frame checked, plus a hash of the sorted pair set where that is cheap).
The signature shared by the largest group of peers (strictly larger than
any other group) is the consensus; a peer outside it *disagrees*.  A disagreeing peer gets no ratio,
and when granularsap itself disagrees no ratio is reported at all.
"""

from __future__ import annotations

import hashlib
import statistics
import time
from dataclasses import asdict, dataclass, field

import numpy as np

from .peers import GRANULARSAP

#: pair sets up to this size are compared exactly (by a hash of the sorted codes)
HASH_LIMIT = 100_000_000

PHASES = ("sort", "candidates", "pairing")
#: runs faster than this (median of the planned repeats) are small frames ...
SMALL_SECONDS = 0.02
#: ... repeated up to this many steady runs ...
SMALL_RUNS = 200
#: ... within this many more seconds
SMALL_BUDGET = 2.0


@dataclass
class PeerResult:
    """What one peer did on one workload (JSON-ready through :func:`dataclasses.asdict`)."""

    peer: str
    status: str  # "ok", "error", "skipped"
    reason: str | None = None
    description: str = ""
    version: str | None = None
    threads: int | None = None
    times: list = field(default_factory=list)  # steady-state runs (the peer's own time if any)
    cpu_times: list = field(default_factory=list)
    wall_times: list | None = None  # harness wall seconds, for peers that time themselves
    self_timed: bool = False  # times are the peer's own figures (LAMMPS's timers)
    seconds: float | None = None  # steady state: median seconds per run (per frame)
    min_seconds: float | None = None  # steady state: the fastest run
    cpu_seconds: float | None = None
    fresh_seconds: float | None = None  # stateful peers: first call on a new engine
    fresh_peak_rss_mb: float | None = None
    warmup_seconds: float | None = None
    peak_rss_mb: float | None = None
    candidates_per_pair: float | None = None  # median candidates tested per pair found
    pairs: int | None = None  # pairs of frame 0
    frame_pairs: list | None = None  # pairs of every frame (trajectories)
    digest: str | None = None
    agrees: bool | None = None
    ratio: float | None = None  # seconds / reference seconds
    phases: dict | None = None  # median granularsap seconds per phase
    stats: dict | None = None  # the engine's last stats
    rebuilds: int = 0
    note: str | None = None


@dataclass
class WorkloadResult:
    name: str
    label: str
    kind: str
    n: int
    n_frames: int
    params: dict
    results: list
    reference: str | None = None
    consensus: list | None = None
    disagreements: list = field(default_factory=list)
    fastest_peer: str | None = None
    best_granularsap: str | None = None
    speedup_vs_fastest: float | None = None  # fastest peer seconds / best granularsap seconds

    def to_dict(self):
        out = asdict(self)
        return out


# ----------------------------------------------------------------------- memory


def _read_status(key):
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(key + ":"):
                return int(line.split()[1]) * 1024
    return None


def _probe_memory():
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        return _read_status("VmHWM") is not None
    except OSError:
        return False


def stabilise_malloc():
    """Make glibc return large blocks to the system at once (for the RSS figures).

    glibc raises its mmap threshold after a large block is freed, so later
    large arrays come from the already resident heap and a run would show no
    RSS growth at all.  Fixing the threshold at 128 KiB (mallopt
    ``M_MMAP_THRESHOLD``) keeps every large array in its own mapping, so the
    high-water mark of each run counts what that run allocated.  Returns True
    when applied (Linux with glibc).
    """
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6")
        m_mmap_threshold = -3
        return bool(libc.mallopt(m_mmap_threshold, 128 * 1024))
    except (OSError, AttributeError):
        return False


MEMORY_METHOD = ("peak RSS above the RSS at the start of each timed run (Linux VmHWM, "
                 "reset via /proc/self/clear_refs)") if _probe_memory() else None


def _available_bytes():
    """MemAvailable of /proc/meminfo, or None."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


class MemoryCeiling:
    """Context manager: a peer may map at most ``fraction`` of the memory available
    at its start (``RLIMIT_AS`` above the process's current size), so that a peer
    whose lists outgrow the machine fails with ``MemoryError``, reported as its
    result, instead of the kernel's out-of-memory killer ending the whole bench.
    A no-op where the limit cannot be set (not Linux)."""

    def __init__(self, fraction=0.8):
        self.fraction = fraction
        self.budget = None

    def __enter__(self):
        self._old = None
        try:
            import resource

            size = _read_status("VmSize")
            avail = _available_bytes()
            if size is None or avail is None:
                return self
            self.budget = int(self.fraction * avail)
            self._old = resource.getrlimit(resource.RLIMIT_AS)
            hard = self._old[1]
            limit = size + self.budget
            if hard != resource.RLIM_INFINITY:
                limit = min(limit, hard)
            resource.setrlimit(resource.RLIMIT_AS, (limit, hard))
        except (ImportError, OSError, ValueError):
            self._old = None
        return self

    def __exit__(self, *exc):
        if self._old is not None:
            import resource

            resource.setrlimit(resource.RLIMIT_AS, self._old)
        return False


class _PeakRSS:
    """Context manager measuring the peak RSS increase (bytes) inside it."""

    def __enter__(self):
        self.delta = None
        if MEMORY_METHOD:
            with open("/proc/self/clear_refs", "w") as fh:
                fh.write("5")
            self.start = _read_status("VmRSS")
        return self

    def __exit__(self, *exc):
        if MEMORY_METHOD:
            self.delta = max(0, _read_status("VmHWM") - self.start)
        return False


# -------------------------------------------------------------------- agreement


def canonical(pairs, n):
    """``(count, digest)`` of a pair array; digest is None above :data:`HASH_LIMIT`."""
    pairs = np.asarray(pairs)
    k = len(pairs)
    if k > HASH_LIMIT:
        return k, None
    if k and (pairs.ndim != 2 or pairs.shape[1] != 2):
        return k, "malformed"
    codes = np.sort(pairs[:, 0].astype(np.int64) * max(n, 1) + pairs[:, 1].astype(np.int64)) \
        if k else np.empty(0, np.int64)
    if k and not np.all(pairs[:, 0] < pairs[:, 1]):
        return k, "not-i<j"
    return k, hashlib.blake2b(codes.tobytes(), digest_size=12).hexdigest()


def find_consensus(signatures):
    """Names in the largest group of ``{name: signature}``, or None on a tie."""
    groups = {}
    for name, sig in signatures.items():
        groups.setdefault(sig, []).append(name)
    if not groups:
        return None
    ranked = sorted(groups.values(), key=len, reverse=True)
    if len(ranked) > 1 and len(ranked[0]) == len(ranked[1]):
        return None  # a tie: nobody can be trusted
    return ranked[0]


def _phase_seconds(stats):
    if not stats:
        return None
    src = stats.get("seconds", stats)
    if not isinstance(src, dict):
        return None
    out = {k: float(src[k]) for k in PHASES if isinstance(src.get(k), (int, float))}
    return out or None


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, (str, int, float, bool)) or obj is None:
        return obj
    return str(obj)


# ---------------------------------------------------------------------- running


def _candidates_per_pair(stats):
    """``candidates_tested / pairs`` from a peer's stats (top level), or None."""
    if not isinstance(stats, dict):
        return None
    tested, pairs = stats.get("candidates_tested"), stats.get("pairs")
    if isinstance(tested, (int, float, np.integer)) and isinstance(pairs, (int, np.integer)) \
            and pairs > 0:
        return float(tested) / float(pairs)
    return None


class _NoPeak:
    """``_PeakRSS`` that measures nothing."""

    delta = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def _timed_run(peer, frame, memory=True):
    """``(pairs, seconds, wall, cpu or None, peak bytes or None)`` of one run;
    ``memory=False`` skips the peak memory (None)."""
    with (_PeakRSS() if memory else _NoPeak()) as mem:
        c0 = time.process_time()
        t0 = time.perf_counter()
        pairs = peer.run(frame)
        t1 = time.perf_counter()
        c1 = time.process_time()
    own = peer.last_seconds()
    if own is not None:
        return pairs, float(own), t1 - t0, None, mem.delta
    return pairs, t1 - t0, t1 - t0, c1 - c0, mem.delta


def run_peer(peer, workload, *, repeats=5, n_threads=1, max_seconds=120.0, tick=None,
             small_runs=0):
    """Run one peer on one workload; return a :class:`PeerResult`.

    ``tick(done, total, seconds_so_far)`` is called after every timed run
    (progress lines of long runs).  ``small_runs``: steady runs of a small
    single-frame workload (see the module docstring); 0 keeps ``repeats``.
    """
    res = PeerResult(peer=peer.name, status="ok", description=peer.description,
                     version=peer.version(), threads=peer.threads_used(n_threads))
    why = peer.unsupported(workload)
    if why:
        res.status, res.reason = "skipped", why
        return res
    n_frames = len(workload.frames)
    notes = []
    ceiling = MemoryCeiling()
    try:
        ceiling.__enter__()
        peer.setup(workload, n_threads)
        t0 = time.perf_counter()
        first = peer.run(0)
        res.warmup_seconds = time.perf_counter() - t0
        res.threads = peer.threads_used(n_threads)
        count, digest = canonical(first, workload.n)
        del first
        res.pairs, res.digest = count, digest
        frame_pairs = [count]
        if n_frames > 1:
            plan = list(range(1, n_frames))
        else:
            plan = [0] * max(int(repeats), 1)
        too_slow = res.warmup_seconds > max_seconds
        if too_slow:
            plan = []
            notes.append(f"timed once: the warm-up took longer than {max_seconds:g} s")
        if peer.stateful and not too_slow:
            peer.close()
            peer.setup(workload, n_threads)
            pairs, res.fresh_seconds, _, _, peak = _timed_run(peer, 0)
            if peak is not None:
                res.fresh_peak_rss_mb = peak / 2**20
            fresh = canonical(pairs, workload.n)
            del pairs
            if fresh != (count, digest):
                res.digest = f"{digest}/fresh:{fresh[1]}"
                notes.append(f"the fresh call found {fresh[0]} pairs, the warm-up {count}")
        peaks, phases, cands, walls, spent = [], [], [], [], 0.0
        last = None
        extra_until = None
        for step, frame in enumerate(_plan_runs(plan, res.times, small_runs, n_frames)):
            if step == len(plan):  # the small-frame extension starts
                extra_until = time.perf_counter() + SMALL_BUDGET
            elif extra_until is not None and time.perf_counter() > extra_until:
                break
            # (the extension's runs repeat a frame whose memory the planned runs
            # measured: resetting the high-water mark and reading it back slows
            # the next small run by a tenth, so they do not)
            pairs, seconds, wall, cpu, peak = _timed_run(peer, frame, step < len(plan))
            res.times.append(seconds)
            res.cpu_times.append(cpu)
            walls.append(wall)
            spent += wall
            if tick is not None and step < len(plan):
                tick(step + 1, len(plan), spent)
            if peak is not None:
                peaks.append(peak)
            stats = peer.last_stats()
            ph = _phase_seconds(stats)
            if ph:
                phases.append(ph)
            cpp = _candidates_per_pair(stats)
            if cpp is not None:
                cands.append(cpp)
            if n_frames > 1:
                frame_pairs.append(len(pairs))
                last = pairs if frame == n_frames - 1 else None
            del pairs
            if spent > max_seconds and step + 1 < len(plan):
                notes.append(f"stopped after {step + 1} of {len(plan)} timed runs "
                             f"(--max-seconds {max_seconds:g})")
                break
        res.self_timed = peer.last_seconds() is not None
        if res.self_timed:
            res.wall_times = walls
        if not res.times:  # timed once: use the warm-up
            own = peer.last_seconds()
            res.times = [res.warmup_seconds if own is None else float(own)]
            res.cpu_times = [None]
        if n_frames > 1:
            res.frame_pairs = frame_pairs
            if last is not None:
                _, tail = canonical(last, workload.n)
                res.digest = f"{res.digest}/{tail}"
        res.seconds = statistics.median(res.times)
        res.min_seconds = min(res.times)
        cpu = [c for c in res.cpu_times if c is not None]
        res.cpu_seconds = statistics.median(cpu) if cpu else None
        res.peak_rss_mb = max(peaks) / 2**20 if peaks else None
        if phases:
            res.phases = {k: statistics.median(p.get(k, 0.0) for p in phases) for k in PHASES}
        stats = peer.last_stats()
        if not cands and _candidates_per_pair(stats) is not None:
            cands = [_candidates_per_pair(stats)]
        res.candidates_per_pair = statistics.median(cands) if cands else None
        res.stats = _jsonable(stats) if stats else None
        res.rebuilds = int(getattr(peer, "rebuilds", 0) or 0)
        remark = peer.note()
        if remark:
            notes.append(remark)
    except MemoryError:
        budget = (f"{ceiling.budget / 2**30:.1f} GiB, 80 % of the memory available"
                  if ceiling.budget else "the memory available")
        res.status, res.reason = "error", f"ran out of memory (allowed {budget})"
    except Exception as exc:  # a failing peer is reported, not fatal
        res.status, res.reason = "error", f"{type(exc).__name__}: {exc}"
    finally:
        try:
            peer.close()
        except Exception as exc:  # a peer that cannot clean up is reported, not fatal
            notes.append(f"close failed: {type(exc).__name__}: {exc}")
        ceiling.__exit__(None, None, None)
    res.note = "; ".join(notes) or None
    return res


def _signature(res):
    if res.frame_pairs is not None:
        return (tuple(res.frame_pairs), res.digest)
    return (res.pairs, res.digest)


def _agrees_on_prefix(res, model):
    """A trajectory peer stopped early (``--max-seconds``) agrees if every frame it
    ran has the consensus's pair count and its first frame the consensus's digest."""
    if res.frame_pairs is None or model.frame_pairs is None or res.digest is None:
        return False
    n = len(res.frame_pairs)
    if n >= len(model.frame_pairs) or res.frame_pairs != model.frame_pairs[:n]:
        return False
    return model.digest is not None and res.digest.split("/")[0] == model.digest.split("/")[0]


def judge(wres):
    """Fill agreement, reference, ratios and the fastest-peer summary of ``wres``."""
    ran = [r for r in wres.results if r.status == "ok"]
    consensus = find_consensus({r.peer: _signature(r) for r in ran})
    wres.consensus = consensus
    agreed = {r.peer: r for r in ran if consensus is not None and r.peer in consensus}
    model = next(iter(agreed.values()), None)
    for r in ran:
        r.agrees = r.peer in agreed or (model is not None and _agrees_on_prefix(r, model))
        if not r.agrees:
            wres.disagreements.append(r.peer)
    by_name = {r.peer: r for r in ran}
    ref = next((by_name[g] for g in GRANULARSAP if g in by_name and by_name[g].agrees), None)
    gsap_disagrees = any(by_name[g].agrees is False for g in GRANULARSAP if g in by_name)
    if ref is None or gsap_disagrees:
        return wres
    wres.reference = ref.peer
    for r in ran:
        if r.agrees and r.seconds and ref.seconds:
            r.ratio = r.seconds / ref.seconds
    others = [r for r in ran if r.agrees and r.peer not in GRANULARSAP]
    ours = [by_name[g] for g in GRANULARSAP if g in by_name and by_name[g].agrees]
    if others and ours:
        fastest = min(others, key=lambda r: r.seconds)
        best = min(ours, key=lambda r: r.seconds)
        wres.fastest_peer, wres.best_granularsap = fastest.peer, best.peer
        wres.speedup_vs_fastest = fastest.seconds / best.seconds
    return wres


def _plan_runs(plan, times, small_runs, n_frames):
    """The frames of the steady runs: ``plan``, then (a small single-frame
    workload, ``small_runs`` given) frame 0 again until ``small_runs`` runs."""
    yield from plan
    if (small_runs <= len(plan) or n_frames != 1 or not times
            or statistics.median(times) >= SMALL_SECONDS):
        return
    for _ in range(small_runs - len(plan)):
        yield 0


def run_workload(workload, peers, *, repeats=5, n_threads=1, max_seconds=120.0,
                 progress=None, tick=None, small_runs=0):
    """Run every peer on ``workload``; return a judged :class:`WorkloadResult`.

    ``progress(peer_result)`` is called after each peer and ``tick(peer, done,
    total, seconds)`` after each timed run, for the CLI's progress lines.
    """
    results = []
    for peer in peers:
        peer_tick = None if tick is None else (lambda d, t, s, p=peer: tick(p, d, t, s))
        res = run_peer(peer, workload, repeats=repeats, n_threads=n_threads,
                       max_seconds=max_seconds, tick=peer_tick, small_runs=small_runs)
        results.append(res)
        if progress is not None:
            progress(res)
    wres = WorkloadResult(name=workload.name, label=workload.label, kind=workload.kind,
                          n=workload.n, n_frames=len(workload.frames),
                          params=_jsonable(workload.params), results=results)
    return judge(wres)
