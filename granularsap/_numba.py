"""The only place that decides numba options for granularsap kernels.

Compilation is cached on disk by default (``cache=True``) so that a warm
``import granularsap`` plus the first call stays fast.  Set the environment
variable ``GRANULARSAP_NO_CACHE=1`` to turn the cache off (for example on a
read-only install).

Threading layer and fork safety
-------------------------------
numba's default threading layer on Linux is GNU OpenMP, and a process that has
run an OpenMP parallel region must not ``fork()``: the child aborts with
"fork() called from a process already using GNU OpenMP, this is unsafe" and a
``multiprocessing`` pool (fork start method, MDAnalysis's ``multiprocessing``
analysis backend) waits forever.  So that granularsap is fork-safe out of the
box, importing it picks a fork-safe layer, unless the application has chosen
one itself:

* nothing is changed if ``NUMBA_THREADING_LAYER`` is set in the environment
  (any value, ``default`` included), if ``numba.config.THREADING_LAYER`` was
  set to something other than ``"default"`` before granularsap was imported,
  or if numba's thread pool is already running (a choice that may use TBB,
  such as ``tbb`` or ``safe``, still gets the wheel's ``libtbb`` preloaded);
* otherwise the layer becomes ``"tbb"`` when Intel TBB can be loaded (the
  PyPI package ``tbb``; its ``libtbb`` is located and preloaded, so a plain
  virtual environment needs no ``LD_LIBRARY_PATH``), else ``"workqueue"``.

An application that sets ``numba.config.THREADING_LAYER`` after importing
granularsap but before the first parallel call still wins.  ``workqueue`` is
fork-safe but not thread-safe (numba aborts the process when two Python
threads launch parallel regions at the same moment), so under ``workqueue``
granularsap runs its parallel kernels one call at a time; install ``tbb`` for
concurrent calls from several threads.  :data:`THREADING_LAYER_SET` records what was done.
"""

from __future__ import annotations

import ctypes
import functools
import os
import sys
import threading
import types
import warnings

import numba

CACHE = os.environ.get("GRANULARSAP_NO_CACHE", "0").lower() in ("", "0", "false", "no")

_OPTIONS = dict(cache=CACHE, nogil=True, fastmath=False, error_model="numpy")

#: The threading layer granularsap set at import ("tbb" or "workqueue"), or
#: None if it left the choice to the application (see the module docstring).
THREADING_LAYER_SET = None


def _tbb_library():
    """Path of ``libtbb`` installed by the ``tbb`` wheel, or None."""
    if not sys.platform.startswith("linux"):
        return None  # elsewhere numba finds the wheel's library on its own, or not at all
    try:
        from importlib import metadata

        files = metadata.files("tbb") or []
    except Exception:  # not installed, or broken metadata
        return None
    for f in files:
        if f.name == "libtbb.so.12":
            path = f.locate()
            if os.path.exists(path):
                return os.fspath(path)
    return None


def _tbb_usable():
    """True if numba's TBB threading layer would load in this process."""
    from numba.np.ufunc import parallel

    def loads():
        # numba's own checks: TBB interface version >= 12060, then its extension
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # numba warns about a too-old TBB
            try:
                parallel._check_tbb_version_compatible()
                from numba.np.ufunc import tbbpool  # noqa: F401
            except Exception:  # ImportError, or anything a broken install raises
                return False
        return True

    if loads():
        return True
    lib = _tbb_library()
    if lib is None:
        return False
    try:
        ctypes.CDLL(lib, mode=ctypes.RTLD_GLOBAL)
    except OSError:
        return False
    return loads()


def _choose_threading_layer():
    """Select a fork-safe threading layer unless the application chose one."""
    global THREADING_LAYER_SET
    from numba.np.ufunc import parallel

    if parallel._is_initialized:
        return None  # a parallel region already ran: too late to change anything
    chosen = os.environ.get("NUMBA_THREADING_LAYER")
    if chosen is None and str(numba.config.THREADING_LAYER).lower() != "default":
        chosen = str(numba.config.THREADING_LAYER)
    if chosen is not None:
        # the application's choice stands; make the tbb wheel's library loadable
        # if that choice may use TBB
        if chosen.lower() in ("tbb", "safe", "threadsafe", "forksafe"):
            _tbb_usable()
        return None
    layer = "tbb" if _tbb_usable() else "workqueue"
    numba.config.THREADING_LAYER = layer
    THREADING_LAYER_SET = layer
    return layer


_choose_threading_layer()


def jit(func):
    """Decorator for serial kernels."""
    return numba.njit(**_OPTIONS)(func)


def hjit(func):
    """Decorator for serial kernels called only from other kernels: numba builds
    no CPython entry point for them (a 34-argument entry is a sizeable function of
    its own to compile on a cold cache).  A call from Python crashes the process
    instead of raising: ``tests/test_kernel_signatures.py`` checks that every call
    of one is inside a kernel."""
    return numba.njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, **_OPTIONS)(func)


def ijit(func):
    """Decorator for small serial helpers, inlined into their callers at numba's
    IR level: no call overhead or argument packing in hot loops, and no
    compilation of their own for the one-off helpers of a kernel (each compiled
    function costs a pipeline and an LLVM module of its own on a cold cache).
    Calls with more arguments than CPython passes one by one cannot be inlined."""
    return numba.njit(inline="always", **_OPTIONS)(func)


_WORKQUEUE_LOCK = threading.Lock()


def _workqueue_in_use():
    try:
        return numba.threading_layer() == "workqueue"
    except ValueError:  # no parallel region yet: the configured layer decides
        return str(numba.config.THREADING_LAYER).lower() == "workqueue"


class _ParallelKernel:
    """A parallel dispatcher that, under the ``workqueue`` layer, runs one call
    at a time: workqueue aborts the process when two threads launch parallel
    regions concurrently.  Any other layer calls straight through."""

    __slots__ = ("_dispatcher", "__dict__")

    def __init__(self, dispatcher):
        self._dispatcher = dispatcher
        functools.update_wrapper(self, dispatcher)

    def __call__(self, *args, **kwargs):
        if _workqueue_in_use():
            with _WORKQUEUE_LOCK:
                return self._dispatcher(*args, **kwargs)
        return self._dispatcher(*args, **kwargs)

    def __getattr__(self, name):
        return getattr(self._dispatcher, name)


def pjit(func):
    """Decorator for parallel kernels (``numba.prange`` loops).

    Kernels must be called from Python, not from other kernels (the returned
    object serialises calls under the ``workqueue`` layer)."""
    return _ParallelKernel(numba.njit(parallel=True, **_OPTIONS)(func))


def serial_twin(kernel):
    """The serial build of a parallel kernel (``prange`` runs as ``range``): no
    thread-pool launch per call, for small inputs and one thread.  A renamed
    copy of the function, so that its compile cache is its own."""
    f = kernel.py_func
    g = types.FunctionType(f.__code__, f.__globals__, f.__name__ + "_serial", f.__defaults__,
                           f.__closure__)
    g.__qualname__ = f.__qualname__ + "_serial"
    g.__doc__ = f.__doc__
    return jit(g)


def max_threads() -> int:
    """Largest thread count numba can use in this process."""
    return numba.config.NUMBA_NUM_THREADS


_POOL = []  # numba's parallel module, once _pool found its pool running


def _pool():
    """numba's parallel module once its thread pool runs and its C entry points of
    the thread count are there, else None (kept once found: a pool, once up,
    stays)."""
    if _POOL:
        return _POOL[0]
    par = sys.modules.get("numba.np.ufunc.parallel")
    if (par is not None and getattr(par, "_is_initialized", False)
            and callable(getattr(par, "_get_num_threads", None))
            and callable(getattr(par, "_set_num_threads", None))):
        _POOL.append(par)
        return par
    return None


def get_threads() -> int:
    """``numba.get_num_threads()``: the calling thread's count.  numba's function
    takes the pool's launch locks on every call (a process lock among them, about
    0.6 us); once the pool runs, the C function it then calls is read directly."""
    par = _pool()
    if par is not None:
        n = par._get_num_threads()
        if n > 0:
            return n
    return numba.get_num_threads()


def _set_threads(n):
    par = _pool()
    if par is not None:  # (n validated: 1 <= n <= max_threads())
        par._set_num_threads(n)
    else:
        numba.set_num_threads(n)


class num_threads:
    """Run a block with ``n_threads`` numba threads, restoring the old value after.

    ``None`` keeps numba's current setting.  Yields the number of threads in use.
    The argument must already be validated (see ``_validate.check_n_threads``).
    (A class, not a generator: entered several times a step by a time loop.)
    """

    __slots__ = ("_n", "_old")

    def __init__(self, n_threads):
        self._n = n_threads
        self._old = None

    def __enter__(self):
        cur = get_threads()
        if self._n is None or self._n == cur:  # nothing to set or restore
            return cur
        _set_threads(self._n)
        self._old = cur
        return self._n

    def __exit__(self, *exc):
        if self._old is not None:
            _set_threads(self._old)
            self._old = None
        return False
