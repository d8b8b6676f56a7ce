"""Input coercion and checks shared by every public function.

Validate once, in the API layer, before any compiled call.  Messages name the
argument, the expectation and what was received.
"""

from __future__ import annotations

import numbers

import numpy as np

from ._numba import max_threads


def as_coords(x, name, *, ncols=3, allow_empty=True, check_finite=True, single_row=False,
              allow_bool=False):
    """Return ``x`` as a C-contiguous float64 ``(n, ncols)`` array of finite values.

    float32 input is widened exactly; integer input is converted; complex,
    object, string and boolean input is a TypeError.  Never down-casts.  With
    ``check_finite=False`` the caller checks finiteness itself.

    ``single_row=True`` reads a ``(ncols,)`` vector as one row (MDAnalysis
    accepts a single coordinate); ``allow_bool=True`` reads booleans as 0 and
    1 (as NumPy does).  Both are off by default: a ``(3,)`` array is refused
    rather than taken for one box or one particle.
    """
    if hasattr(x, "positions") and not isinstance(x, np.ndarray):
        # MDAnalysis AtomGroup or similar
        x = x.positions
    try:
        arr = np.asarray(x)
    except Exception as exc:  # pragma: no cover - exotic inputs
        raise TypeError(f"{name} must be an array of numbers, got {type(x).__name__}") from exc
    if arr.dtype.kind == "b" and not allow_bool:
        raise TypeError(f"{name} must be an array of real numbers, got dtype bool; convert "
                        f"it explicitly (e.g. {name}.astype(float)) if 0 and 1 are meant")
    if arr.dtype.kind not in "fiub":
        raise TypeError(f"{name} must be an array of real numbers, got dtype {arr.dtype}")
    if arr.dtype.kind == "f" and arr.dtype.itemsize > 8:
        raise TypeError(f"{name} must be float64 or narrower, got dtype {arr.dtype}; "
                        "convert it explicitly if the precision loss is acceptable")
    if arr.ndim == 1 and arr.shape[0] == ncols and ncols > 1:
        if not single_row:
            raise ValueError(f"{name} must have shape (n, {ncols}), got {arr.shape}; for a "
                             f"single row pass {name}.reshape(1, {ncols})")
        arr = arr.reshape(1, ncols)
    if arr.ndim != 2 or arr.shape[1] != ncols:
        raise ValueError(f"{name} must have shape (n, {ncols}), got {arr.shape}")
    if not allow_empty and arr.shape[0] == 0:
        raise ValueError(f"{name} must not be empty")
    arr = np.ascontiguousarray(arr, dtype=np.float64)
    if check_finite and not np.isfinite(arr).all():
        bad = int(np.flatnonzero(~np.isfinite(arr).all(axis=1))[0])
        raise ValueError(f"{name} must be finite, got NaN or inf in row {bad}")
    return arr


def as_vector(x, name, n, *, nonnegative=True):
    """Return ``x`` (scalar or length-``n``) as a float64 vector of length ``n``."""
    arr = np.asarray(x)
    if arr.dtype.kind not in "fiub":
        raise TypeError(f"{name} must be real numbers, got dtype {arr.dtype}")
    if arr.ndim == 0:
        arr = np.full(n, float(arr), dtype=np.float64)
    elif arr.ndim != 1 or arr.shape[0] != n:
        raise ValueError(f"{name} must be a scalar or have shape ({n},), got {arr.shape}")
    arr = np.ascontiguousarray(arr, dtype=np.float64)
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite, got NaN or inf")
    if nonnegative and arr.size and arr.min() < 0:
        bad = int(np.argmin(arr))
        raise ValueError(f"{name} must be non-negative, got {float(arr[bad])!r} at index {bad}")
    return arr


def as_scalar(x, name, *, nonnegative=True, positive=False):
    """Return ``x`` as a finite Python float."""
    if isinstance(x, (bool, np.bool_)) or not isinstance(x, (numbers.Real, np.number)):
        if not (isinstance(x, np.ndarray) and x.ndim == 0 and x.dtype.kind in "fiu"):
            raise TypeError(f"{name} must be a real number, got {type(x).__name__}")
    val = float(x)
    if not np.isfinite(val):
        raise ValueError(f"{name} must be finite, got {val}")
    if positive and val <= 0:
        raise ValueError(f"{name} must be positive, got {val}")
    if nonnegative and val < 0:
        raise ValueError(f"{name} must be non-negative, got {val}")
    return val


def check_n_threads(n_threads):
    """Validate ``n_threads`` (None or an int in [1, numba's maximum])."""
    if n_threads is None:
        return None
    if isinstance(n_threads, (bool, np.bool_)) or not isinstance(n_threads, (numbers.Integral,)):
        raise TypeError(f"n_threads must be an int or None, got {type(n_threads).__name__}")
    n_threads = int(n_threads)
    top = max_threads()
    if not 1 <= n_threads <= top:
        raise ValueError(f"n_threads must be between 1 and {top} (NUMBA_NUM_THREADS), "
                         f"got {n_threads}")
    return n_threads
