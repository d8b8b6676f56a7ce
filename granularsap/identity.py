"""Contact identity across calls: which contact of the previous call each
contact of this call continues, so that a time-stepping script can carry a
history per contact (the tangential spring of a Mindlin or Cundall-Strack
contact, a rolling angle) with one gather per step.

Two trackers share one interface (``previous_rows``, ``ended_rows``,
:meth:`~ContactIdentity.carry`):

* :class:`PairIdentity` follows particle pairs, the particles known by ids
  (so that insertions and deletions keep identity) or by row, and with every
  periodic image by their lattice shift too.  :class:`~granularsap.NeighborSearch`
  and :class:`~granularsap.ContactSearch` own one when built with
  ``identity=True``.
* :class:`ContactIdentity` follows contacts given by integer keys, any number
  of int64 columns per contact (a sphere-wall contact: sphere id, wall,
  element).

The rules are in ``docs/identity.md``; the kernels and their cost in
``granularsap/kernels/identity.py``.  Both trackers are O(contacts +
particles) per call, without a Python loop over contacts, and give the same
answer on any thread count.
"""

from __future__ import annotations

import numpy as np

from ._numba import get_threads, num_threads
from ._validate import check_n_threads
from .kernels import identity as kern
from .kernels.radixsort import MAX_PASSES, RADIX

__all__ = ["ContactIdentity", "PairIdentity", "as_ids"]

#: below this many rows the serial kernels run (a parallel region costs more)
_PARALLEL_MIN = 50000
_NO_SHIFTS = np.zeros((0, 3), np.int64)
_NO_ROWS = np.zeros(0, np.int64)
_NO_KEYS = np.zeros((0, 1), np.int64)
#: pass 2's buffers before it first has work (``PairIdentity._rest_buffers``)
_NO_REST = (np.zeros((2, 0), np.uint64), np.zeros((2, 0), np.int64),
            np.zeros((2, 0), np.uint64), np.zeros((2, 0), np.int64),
            np.zeros((2, 0), np.int64))


def as_ids(ids, n, name="ids"):
    """Validated ``(n,)`` int64 particle ids (uniqueness is checked when they are
    matched, by :meth:`PairIdentity.update`).

    Examples
    --------
    >>> as_ids([3, 1, 2], 3).tolist()
    [3, 1, 2]
    """
    arr = np.asarray(ids)
    if arr.dtype.kind not in "iu":
        if arr.size == 0 and arr.dtype.kind in "fb":
            arr = arr.astype(np.int64)
        else:
            raise TypeError(f"{name} must be integers (one unique id per particle), got "
                            f"dtype {arr.dtype}")
    if arr.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), one per particle, got {arr.shape}")
    if arr.dtype == np.uint64 and arr.size and arr.max() > np.iinfo(np.int64).max:
        bad = int(np.argmax(arr))
        raise ValueError(f"{name} must fit in int64, got {int(arr[bad])} at index {bad}")
    return np.ascontiguousarray(arr, dtype=np.int64)


def _repeated_keys(keys, first, second):
    """The error of ``ContactIdentity.update`` for rows ``first`` and ``second``
    holding the same keys."""
    return ValueError(f"keys must be unique rows: rows {first} and {second} are both "
                      f"{keys[second].tolist()}")


def _bounds(k, chunks):
    """``chunks + 1`` increasing row bounds from 0 to ``k``."""
    if chunks == 1:
        return np.array([0, k], np.int64)
    return np.arange(chunks + 1, dtype=np.int64) * k // chunks


def _grow(buf, size, dtype, extra=()):
    """``buf`` if it holds ``size`` rows, else a new buffer with an eighth more."""
    if buf is not None and len(buf) >= size:
        return buf
    return np.empty((size + size // 8,) + extra, dtype)


class _Rows:
    """What both trackers share: double-buffered row maps and :meth:`carry`."""

    def __init__(self, n_threads):
        self.n_threads = check_n_threads(n_threads)
        self._sets = [{}, {}]
        self._set = 1
        self._k_prev = 0
        self._k = None
        self.previous_rows = None
        self.ended_rows = None
        self._new = None

    def _threads(self, rows):
        """(kernels, chunks) for ``rows`` rows under the thread count in force."""
        t = get_threads()
        if t == 1 or rows < _PARALLEL_MIN:
            return kern.serial, 1
        return kern, t

    def _publish(self, k, k_prev, fill_rows, matched, chunks, kernels):
        """Write this call's maps into the buffer set the previous call did not use:
        ``fill_rows(prev_rows)`` writes ``previous_rows``; ``matched`` flags the
        previous rows found."""
        s = self._sets[1 - self._set]
        s["prev"] = _grow(s.get("prev"), k, np.int64)
        prev = s["prev"][:k]
        ended = fill_rows(prev, s)
        if ended is None:
            ended = self._unmatched(matched, k_prev, chunks, kernels, s, "ended")
        self._set = 1 - self._set
        self.previous_rows, self.ended_rows = prev, ended
        self._k_prev, self._k = k_prev, k
        self._new = None

    def _matched(self, k_prev):
        """Flags of the previous rows found, zeroed, in a buffer padded to whole
        words of eight rows (padding set: ``unmatched_words`` reads words)."""
        s = self._sets[1 - self._set]
        padded = k_prev + (-k_prev) % 8
        s["matched"] = _grow(s.get("matched"), padded, np.uint8)
        matched = s["matched"][:k_prev]
        matched[:] = 0
        s["matched"][k_prev:padded] = 1
        return matched

    def _unmatched(self, matched, k_prev, chunks, kernels, s, name):
        """The rows ``q < k_prev`` with ``matched[q] == 0``, ascending, in buffer
        ``s[name]`` (two passes of ``unmatched_words``)."""
        padded = k_prev + (-k_prev) % 8
        flags = s["matched"][:padded]
        if chunks == 1:  # one pass into a buffer with room for every row
            s[name] = _grow(s.get(name), k_prev, np.int64)
            return s[name][:kern.unmatched_into(flags, s[name])]
        bounds = _bounds(padded // 8, chunks) * 8
        counts = np.zeros(chunks, np.int64)
        kernels.unmatched_words(flags, bounds, counts, _NO_ROWS, False)
        m = int(counts.sum())
        offsets = np.zeros(chunks, np.int64)
        offsets[1:] = np.cumsum(counts)[:-1]
        s[name] = _grow(s.get(name), m, np.int64)
        out = s[name][:m]
        kernels.unmatched_words(flags, bounds, offsets, out, True)
        return out

    def detach(self):
        """Replace ``previous_rows`` and ``ended_rows`` by copies (they then stay
        valid after any later call)."""
        if self.previous_rows is not None:
            self.previous_rows = self.previous_rows.copy()
            self.ended_rows = self.ended_rows.copy()

    @property
    def nbytes(self):
        """Bytes of the buffers the tracker keeps between calls."""
        seen, total = set(), 0
        values = [*vars(self).values(), *self._sets[0].values(), *self._sets[1].values()]
        for value in list(values):
            if isinstance(value, tuple):  # (pass 2's sort buffers)
                values.extend(value)
        for value in values:
            if isinstance(value, np.ndarray) and id(value) not in seen:
                seen.add(id(value))
                total += value.nbytes
        return total

    def carry(self, history, fill=0.0, out=None):
        """A history array of the previous call's contacts, moved to this call's rows.

        Parameters
        ----------
        history : (k_prev, ...) array_like
            One row per contact of the previous call's result.
        fill : scalar or array_like, optional
            Value of the rows of new contacts (default 0).
        out : (k, ...) ndarray, optional
            Where to write (same dtype as ``history``, not overlapping it); a
            new array by default.

        Returns
        -------
        (k, ...) ndarray
            ``history[previous_rows]``, ``fill`` where ``previous_rows == -1``.

        Examples
        --------
        >>> import numpy as np
        >>> track = ContactIdentity()
        >>> _ = track.update([[1, 2], [2, 3]])
        >>> _ = track.update([[2, 3], [4, 5]])
        >>> track.carry(np.array([10.0, 20.0]), fill=-1.0).tolist()
        [20.0, -1.0]
        """
        prev = self.previous_rows
        if prev is None:
            raise ValueError("carry needs a previous update: there is no result to carry "
                             "from yet")
        h = np.asarray(history)
        if h.ndim == 0 or h.shape[0] != self._k_prev:
            raise ValueError(f"history must have one row per contact of the previous call's "
                             f"result ({self._k_prev} rows), got shape {h.shape}")
        shape = (len(prev),) + h.shape[1:]
        if out is None:
            out = np.empty(shape, h.dtype)
        else:
            if not isinstance(out, np.ndarray):
                raise TypeError(f"out must be a numpy array, got {type(out).__name__}")
            if out.shape != shape or out.dtype != h.dtype:
                raise ValueError(f"out must have shape {shape} and dtype {h.dtype}, got "
                                 f"shape {out.shape} and dtype {out.dtype}")
            if np.shares_memory(out, h):
                raise ValueError("out must not overlap history (carry from one buffer into "
                                 "another, e.g. two that alternate)")
        if self._k_prev == 0 or not len(prev):
            out[...] = fill
            return out
        if (h.dtype == np.float64 and h.ndim <= 2 and h.flags.c_contiguous
                and out.flags.c_contiguous and isinstance(fill, (float, int))
                and not isinstance(fill, bool)):
            # the common history (float64 rows, a number for new contacts) in one pass
            w = h.shape[1] if h.ndim == 2 else 1
            kern.carry_rows(h.reshape(len(h), w), prev, float(fill), out.reshape(len(prev), w))
            return out
        np.take(h, prev, axis=0, out=out, mode="clip")
        if self._new is None:
            self._new = np.flatnonzero(prev < 0)
        if len(self._new):
            out[self._new] = fill
        return out


class ContactIdentity(_Rows):
    """Rows of the same contact in consecutive calls, contacts given by integer keys.

    Each call gives the contacts of one step as rows of integer keys (any
    number of columns, the same on every call; for a sphere-wall contact the
    sphere's id, the wall and the mesh element).  Two rows of consecutive calls
    are the same contact when their keys are equal.

    Parameters
    ----------
    n_threads : int, optional
        numba threads for each call (restored afterwards); results do not
        depend on it.

    Attributes
    ----------
    previous_rows : (k,) int64 ndarray
        After :meth:`update`: the row of each contact in the previous call, -1 for
        a new one.
    ended_rows : (m,) int64 ndarray
        Rows of the previous call whose contact did not continue, ascending.

    Notes
    -----
    The arrays of a call stay valid and unchanged until the call after next
    (two sets of buffers alternate).  O(rows) per call: a hash table of the
    previous keys, probed by every row.

    Examples
    --------
    >>> track = ContactIdentity()
    >>> track.update([[7, 0, 3], [8, 0, 3]]).tolist()
    [-1, -1]
    >>> track.update([[8, 0, 3], [9, 1, 0]]).tolist(), track.ended_rows.tolist()
    ([1, -1], [0])
    """

    def __init__(self, *, n_threads=None):
        super().__init__(n_threads)
        self._prev_keys = None
        self._slots = np.zeros(0, np.int64)
        self._shift = 64

    def update(self, keys):
        """Match this call's contacts to the previous call's.

        Parameters
        ----------
        keys : (k, w) array_like of int
            One row of ``w`` integer keys per contact, rows unique.

        Returns
        -------
        (k,) int64 ndarray
            ``previous_rows``.
        """
        arr = np.asarray(keys)
        if arr.ndim == 1 and arr.size == 0:
            arr = arr.reshape(0, 0 if self._prev_keys is None else self._prev_keys.shape[1])
        if arr.dtype.kind not in "iu":
            if arr.size == 0:
                arr = arr.astype(np.int64)
            else:
                raise TypeError(f"keys must be integers, got dtype {arr.dtype}")
        if arr.ndim != 2 or arr.shape[1] == 0 and arr.shape[0]:
            raise ValueError(f"keys must have shape (k, w), one row of w >= 1 keys per "
                             f"contact, got {arr.shape}")
        keys = np.array(arr, dtype=np.int64, order="C")  # kept for the next call
        prev = self._prev_keys
        if prev is not None and prev.shape[1] != keys.shape[1] and len(prev) and len(keys):
            raise ValueError(f"keys must have the same columns on every call: "
                             f"{prev.shape[1]} before, {keys.shape[1]} now")
        k = len(keys)
        k_prev = 0 if prev is None else len(prev)
        size = 1 << max(4, int(2 * max(k, 1) - 1).bit_length())
        shift = 64 - (size.bit_length() - 1)
        slots = np.empty(size, np.int64)
        if k < _PARALLEL_MIN or self.n_threads == 1:
            # one chunk (as ``_threads`` decides): one serial kernel, no thread setting
            self._update_one(keys, shift, slots, k, k_prev)
            self._prev_keys, self._slots, self._shift = keys, slots, shift
            return self.previous_rows
        with num_threads(self.n_threads):
            kernels, chunks = self._threads(k)
            first, second = kern.key_table(keys, shift, slots)
            if first >= 0:
                raise _repeated_keys(keys, first, second)
            matched = self._matched(k_prev)

            def fill_rows(out, _):
                if k_prev == 0 or k == 0:
                    out[:] = -1
                    return None
                kernels.match_keys(keys, prev, self._shift, self._slots, _bounds(k, chunks),
                                   out, matched)
                return None

            self._publish(k, k_prev, fill_rows, matched, chunks, kernels)
        self._prev_keys, self._slots, self._shift = keys, slots, shift
        return self.previous_rows

    def _update_one(self, keys, shift, slots, k, k_prev):
        """``update`` of one chunk in one kernel call (``match_keys_one``): the maps
        in the buffer set the previous call did not use, published as
        ``_publish`` does once the keys are found unique."""
        s = self._sets[1 - self._set]
        s["prev"] = _grow(s.get("prev"), k, np.int64)
        prev_rows = s["prev"][:k]
        padded = k_prev + (-k_prev) % 8
        s["matched"] = _grow(s.get("matched"), padded, np.uint8)
        flags = s["matched"][:padded]  # (zeroed and padded by the kernel)
        s["ended"] = _grow(s.get("ended"), k_prev, np.int64)
        prev_keys = self._prev_keys if self._prev_keys is not None else _NO_KEYS
        first, second, ended = kern.match_keys_one(keys, shift, slots, prev_keys, self._shift,
                                                   self._slots, k_prev, prev_rows, flags,
                                                   s["ended"])
        if first >= 0:
            raise _repeated_keys(keys, first, second)
        self._set = 1 - self._set
        self.previous_rows, self.ended_rows = prev_rows, s["ended"][:ended]
        self._k_prev, self._k = k_prev, k
        self._new = None


class PairIdentity(_Rows):
    """Rows of the same particle pair in consecutive calls.

    A pair of this call continues a pair of the previous call when its two
    particles are the same (by ``ids``, or by row when no ids are given) and,
    with ``shifts=True`` (every periodic image), its lattice shift is the same
    once each particle's own jump by whole cell vectors between the two calls
    is taken out.  With clump labels, the clump pairs touched (by label) get
    their own identity: ``clump_pairs``, ``previous_clump_rows``,
    ``ended_clump_rows``, ``carry(h, clumps=True)``.

    Parameters
    ----------
    shifts : bool, optional
        Whether pairs come with lattice shifts (``periodic_images="all"``).
    n_threads : int, optional
        numba threads for each call (restored afterwards); results do not
        depend on it.

    Notes
    -----
    The arrays of a call stay valid and unchanged until the call after next.
    Fastest when both calls list the pairs of each particle together, as the
    searches do (``granularsap/kernels/identity.py``); correct in any order.

    Examples
    --------
    >>> import numpy as np
    >>> track = PairIdentity()
    >>> track.update(np.array([[0, 1], [1, 2]]), 3, ids=[10, 11, 12]).tolist()
    [-1, -1]
    >>> # particle 10 deleted, 13 inserted, rows reordered
    >>> track.update(np.array([[0, 1], [1, 2]]), 3, ids=[13, 12, 11]).tolist()
    [-1, 1]
    >>> track.ended_rows.tolist()
    [0]
    """

    def __init__(self, *, shifts=False, n_threads=None):
        super().__init__(n_threads)
        self.shifts = bool(shifts)
        self._prev = None  # (pairs, shifts, n, ids, positions)
        self._dense = np.zeros(0, np.int64)
        self._hkeys = np.zeros(0, np.int64)
        self._hvals = np.zeros(0, np.int64)
        self._todo = None  # this call's pairs the in-step pass left
        self._rest = None  # pass 2's sort buffers (rest_sort)
        self._clumps = None
        self.clump_pairs = None
        self._entries = None  # (list, entries) of the previous call, when increasing
        #: how the last call matched: "entries" (one kept list), "pairs", "nothing"
        self.matched_by = None
        self._checked = None

    # ---------------------------------------------------------------- ids
    def _map(self, n, ids, prev):
        """The previous row of every particle, or -1: an (n,) int64 array, or None
        when every row is its own previous row (below the previous count)."""
        n_prev = prev[2]
        prev_ids = prev[3]
        if (ids is None) != (prev_ids is None) and n and n_prev:
            raise ValueError("ids must be given on every call or on none: the previous call "
                             f"{'had' if prev_ids is not None else 'had no'} ids")
        if ids is not None and prev_ids is None:
            return self._match_ids(_NO_ROWS, ids)  # checks that they are unique
        if ids is None or prev_ids is None:
            return None
        if len(ids) == len(prev_ids) and kern.same_ids(ids, prev_ids):
            return None
        return self._match_ids(prev_ids, ids)

    def _match_ids(self, prev_ids, ids):
        n = len(ids)
        m = np.empty(n, np.int64)
        if n == 0:
            return m
        lo, hi = int(ids.min()), int(ids.max())
        if len(prev_ids):
            lo, hi = min(lo, int(prev_ids.min())), max(hi, int(prev_ids.max()))
        if hi - lo < 4 * (n + len(prev_ids)) + 1024:
            if len(self._dense) < hi - lo + 1:
                self._dense = np.empty(hi - lo + 1 + (hi - lo) // 8, np.int64)
            first, second = kern.map_ids_dense(prev_ids, ids, lo, self._dense[:hi - lo + 1], m)
        else:
            size = 1 << max(4, int(2 * n - 1).bit_length())
            if len(self._hkeys) != size:
                self._hkeys = np.empty(size, np.int64)
                self._hvals = np.empty(size, np.int64)
            shift = 64 - (size.bit_length() - 1)
            first, second = kern.map_ids_hashed(prev_ids, ids, shift, self._hkeys, self._hvals,
                                                m)
        if first >= 0:
            raise ValueError(f"ids must be unique, one per particle: id {int(ids[second])} is "
                             f"at rows {int(first)} and {int(second)}")
        return m

    def _jumps(self, positions, cell, pbc, m, prev):
        """(n, 3) int64: whole cell vectors each particle moved since the previous call."""
        n = len(positions)
        jumps = np.zeros((n, 3), np.int64)
        if cell is None or prev[4] is None or not n:
            return jumps
        if m is None:
            m = np.arange(n, dtype=np.int64)
            m[prev[2]:] = -1
        has = m >= 0
        moved = positions[has] - prev[4][m[has]]
        frac = np.rint(moved @ np.linalg.inv(cell))
        frac[:, ~np.asarray(pbc, bool)] = 0.0
        jumps[has] = frac.astype(np.int64)
        return jumps

    # --------------------------------------------------------------- pairs
    def update(self, pairs, n, *, ids=None, shifts=None, positions=None, cell=None,
               pbc=None, labels=None, radii=None, skin=0.0, borrow=False, entries=None):
        """Match this call's pairs to the previous call's.

        Parameters
        ----------
        pairs : (k, 2) int64 ndarray
            Rows ``i <= j`` of the two particles of each pair, each pair once.
        n : int
            Number of particles of this call.
        ids : (n,) array_like of int, optional
            Unique id of every particle (given on every call or on none).
        shifts : (k, 3) int64 ndarray, optional
            Lattice shift of each pair (``shifts=True``): the vector from ``i``
            to ``j`` is ``positions[j] - positions[i] + shifts @ cell``.
        positions : (n, 3) ndarray, optional
            Positions as given to the search (``shifts=True``): with the
            previous call's, they tell each particle's jump by whole cell
            vectors (less than half a cell of real motion between calls).
        cell : (3, 3) ndarray, optional
            Cell vectors (rows), None for open boundaries (``shifts=True``).
        pbc : (3,) bools, optional
            Periodic axes of ``cell``.
        labels : (n,) int64 ndarray, optional
            Clump label of every particle: clump pairs get their identity too.
        radii : (n,) ndarray of float, optional
            Accepted for callers that pass the searches' ranges; the matching
            does not need them.
        skin : float, optional
            Likewise (with ``radii``).
        borrow : bool, optional
            Keep ``pairs`` and ``shifts`` (and ``entries``) without copying them
            (the caller keeps them unchanged until the next call).
        entries : (list, (k,) int64 ndarray), optional
            A hint from a search: ``pairs`` re-tested a kept list, the first item
            naming that list, the array the entry of each pair in it (increasing).
            When the previous call gave the same list and the particles are the
            same rows, pairs are matched by entry (a merge), else as usual.

        Returns
        -------
        (k,) int64 ndarray
            ``previous_rows``.
        """
        pairs = np.ascontiguousarray(pairs, dtype=np.int64).reshape(-1, 2)
        k = len(pairs)
        if ids is not None:
            ids = as_ids(ids, n)
        if self.shifts:
            if shifts is None:
                raise ValueError("shifts must be given: this tracker matches lattice shifts "
                                 "(shifts=True)")
            shifts = np.ascontiguousarray(shifts, dtype=np.int64).reshape(-1, 3)
        else:
            shifts = _NO_SHIFTS
        if not borrow:
            pairs = pairs.copy()
            shifts = shifts.copy()
        prev = self._prev or (np.zeros((0, 2), np.int64), _NO_SHIFTS, 0, None, None)
        with num_threads(self.n_threads):
            m = self._map(n, ids, prev)
            k_prev = len(prev[0])
            kernels, chunks = self._threads(k)
            prev_entries = self._entries
            same_list = (entries is not None and prev_entries is not None and m is None
                         and int(n) == prev[2] and prev_entries[0] == entries[0]
                         and len(prev_entries[1]) == k_prev and len(entries[1]) == k)
            matched = self._matched(k_prev)

            def fill_rows(out, sets):
                self.matched_by = "nothing"
                if k_prev == 0 or k == 0:
                    out[:] = -1
                    return None
                self.matched_by = "entries"
                if same_list:
                    done, ended = self._by_entry(entries[1], prev_entries[1], out, matched,
                                                 kernels, chunks, sets)
                    if done:
                        return ended
                self.matched_by = "pairs"
                jumps = (self._jumps(positions, cell, pbc, m, prev) if self.shifts
                         else _NO_SHIFTS)
                if chunks == 1:
                    return self._match_one(pairs, m, prev, shifts, jumps, out, sets)
                return self._match(pairs, m, prev, shifts, jumps, out, matched, kernels, chunks,
                                   sets)

            self._publish(k, k_prev, fill_rows, matched, chunks, kernels)
            self._track_clumps(pairs, labels)
            self._entries = None
            if entries is not None:
                e = np.ascontiguousarray(entries[1], dtype=np.int64)
                if len(e) == k and self._rising(e, kernels, chunks):
                    self._entries = (entries[0], e if borrow else e.copy())
            self._checked = None
        keep = None
        if self.shifts and positions is not None:
            keep = np.array(positions, dtype=np.float64)
        self._prev = (pairs, shifts, int(n), None if ids is None else ids.copy(), keep)
        return self.previous_rows

    def _by_entry(self, e, e_prev, out, matched, kernels, chunks, sets):
        """Match by entry in one kept list (``match_entries``): (True, the ended
        rows, or None for ``_publish`` to find them), or (False, None), nothing
        written that counts, when this call's entries do not increase.  One chunk
        takes one serial call, the ended rows included (``match_entries_one``)."""
        e = np.ascontiguousarray(e, dtype=np.int64)
        if chunks == 1:
            k_prev = len(matched)
            flags = sets["matched"][:k_prev + (-k_prev) % 8]  # padded, as _matched made it
            sets["ended"] = _grow(sets.get("ended"), k_prev, np.int64)
            ended = kern.match_entries_one(e_prev, e, out, flags, sets["ended"])
            if ended >= 0:
                self._checked = e
                return True, sets["ended"][:ended]
            matched[:] = 0
            return False, None
        bounds = _bounds(len(e), chunks)
        rising = np.zeros(chunks, np.uint8)
        kernels.match_entries(e_prev, e, bounds, out, matched, rising)
        if rising.all() and self._joins_rise(e, bounds):
            self._checked = e
            return True, None
        matched[:] = 0
        return False, None

    @staticmethod
    def _joins_rise(e, bounds):
        return all(e[b - 1] < e[b] for b in bounds[1:-1] if 0 < b < len(e))

    def _rising(self, e, kernels, chunks):
        """Whether ``e`` increases (already known when ``_by_entry`` merged it)."""
        if self._checked is e:
            return True
        bounds = _bounds(len(e), chunks)
        rising = np.zeros(chunks, np.uint8)
        kernels.entries_rising(e, bounds, rising)
        return bool(rising.all()) and self._joins_rise(e, bounds)

    def _step(self, kernels, mapped):
        """Pass 1's kernel in ``kernels`` for particles mapped by ids or not and
        with or without shifts (``match_in_step``)."""
        return getattr(kernels, "match_in_step" + ("_ids" if mapped else "")
                       + ("_shifts" if self.shifts else ""))

    @staticmethod
    def _reach(k, k_prev):
        """Previous rows a chunk's cursor looks through to place itself."""
        return int(min(k_prev, 4096 + 2 * abs(k - k_prev)))

    @staticmethod
    def _too_many(n_prev):
        return ValueError(f"contact identity follows up to 2**32 particles, the previous "
                          f"call had {n_prev}")

    def _match(self, pairs, m, prev, shifts, jumps, out, matched, kernels, chunks, sets):
        """The general matching (``kernels/identity.py``): pass 1 follows the
        previous list with a cursor, pass 2 matches what it left against the
        previous rows it left, both sorted by pair.  Returns the ended rows."""
        k = len(pairs)
        prev_pairs = prev[0]
        k_prev = len(prev_pairs)
        bounds = _bounds(k, chunks)
        self._todo = todo = _grow(self._todo, k, np.int64)
        todo_counts = np.zeros(chunks, np.int64)
        mapped = m is not None
        m = m if mapped else _NO_ROWS
        self._step(kernels, mapped)(pairs, m, prev[2], shifts, jumps, prev_pairs, prev[1],
                                    bounds, self._reach(k, k_prev), out, matched, todo,
                                    todo_counts)
        left = self._unmatched(matched, k_prev, chunks, kernels, sets, "left")
        n_todo = int(todo_counts.sum())
        self._last_counts = (n_todo, len(left))
        sets["ended"] = _grow(sets.get("ended"), len(left), np.int64)
        ended = sets["ended"]
        if not len(left) or not n_todo:
            ended[:len(left)] = left
            return ended[:len(left)]
        if prev[2] >= 2**32:
            raise self._too_many(prev[2])
        keys, rows, scratch_keys, scratch_rows, counts, sorted_in = self._rest_buffers(
            max(len(left), n_todo))
        kernels.rest_sort(pairs, m, mapped, prev[2], self.shifts, shifts, jumps, prev_pairs,
                          prev[1], bounds, todo, todo_counts, n_todo, left, keys, rows,
                          scratch_keys, scratch_rows, counts, sorted_in)
        done = [(keys[t], rows[t]) if sorted_in[t] else (scratch_keys[t], scratch_rows[t])
                for t in range(2)]
        kern.rest_merge(pairs, m, mapped, prev[2], self.shifts, shifts, jumps, prev_pairs,
                        prev[1], done[0][0][:len(left)], done[0][1][:len(left)],
                        done[1][0][:n_todo], done[1][1][:n_todo], out, matched)
        return ended[:kern.rest_ended(left, matched, ended)]

    def _rest_buffers(self, cap):
        """Pass 2's sort buffers (``rest_sort``), kept, with room for ``cap`` rows
        in each of its two lists."""
        rest = self._rest
        if rest is None or rest[0].shape[1] < cap:
            cap += cap // 4 + 64
            rest = self._rest = (np.empty((2, cap), np.uint64), np.empty((2, cap), np.int64),
                                 np.empty((2, cap), np.uint64), np.empty((2, cap), np.int64),
                                 np.empty((2, MAX_PASSES * RADIX), np.int64),
                                 np.zeros(2, np.uint8))
        return rest

    def _match_one(self, pairs, m, prev, shifts, jumps, out, sets):
        """``_match`` of one chunk in two serial kernel calls, pass 1 and then the
        rest (``rest_one``): a small call's matching without Python steps
        between its parts.  Returns the ended rows."""
        k = len(pairs)
        prev_pairs = prev[0]
        k_prev = len(prev_pairs)
        self._todo = todo = _grow(self._todo, k, np.int64)
        sets["left"] = left = _grow(sets.get("left"), k_prev, np.int64)
        sets["ended"] = ended = _grow(sets.get("ended"), k_prev, np.int64)
        flags = sets["matched"][:k_prev + (-k_prev) % 8]  # (as _matched zeroed and padded it)
        mapped = m is not None
        m = m if mapped else _NO_ROWS
        todo_counts = np.zeros(1, np.int64)
        self._step(kern.serial, mapped)(pairs, m, prev[2], shifts, jumps, prev_pairs, prev[1],
                                        np.array([0, k], np.int64), self._reach(k, k_prev), out,
                                        flags[:k_prev], todo, todo_counts)
        n_todo = int(todo_counts[0])
        # pass 2's buffers as large as its work, made when it first has more
        rest = self._rest if self._rest is not None else _NO_REST
        while True:
            n_ended, n_left = kern.rest_one(pairs, m, mapped, prev[2], self.shifts, shifts,
                                            jumps, prev_pairs, prev[1], n_todo, out, flags, todo,
                                            left, *rest[:5], ended)
            if n_ended != -2:
                break
            rest = self._rest_buffers(max(int(n_left), n_todo))
        self._last_counts = (n_todo, int(n_left))
        if n_ended < 0:
            raise self._too_many(prev[2])
        return ended[:n_ended]

    # -------------------------------------------------------------- clumps
    def _track_clumps(self, pairs, labels):
        if labels is None:
            self._clumps = None
            self.clump_pairs = None
            return
        if self._clumps is None:
            self._clumps = ContactIdentity()
        la = labels[pairs[:, 0]]
        lb = labels[pairs[:, 1]]
        lo = np.minimum(la, lb)
        hi = np.maximum(la, lb)
        order = np.lexsort((hi, lo))
        lo, hi = lo[order], hi[order]
        first = np.ones(len(lo), bool)
        first[1:] = (lo[1:] != lo[:-1]) | (hi[1:] != hi[:-1])
        self.clump_pairs = np.stack([lo[first], hi[first]], axis=1)
        self._clumps.update(self.clump_pairs)

    def _clump_tracker(self):
        if self._clumps is None or self.clump_pairs is None:
            raise ValueError("clump identity needs clump labels (ContactSearch.update(..., "
                             "clump_ids=...)) on this call")
        return self._clumps

    @property
    def previous_clump_rows(self):
        """(c,) int64: row of each clump pair in the previous call's ``clump_pairs``,
        or -1."""
        return self._clump_tracker().previous_rows

    @property
    def ended_clump_rows(self):
        """(m,) int64: rows of the previous call's ``clump_pairs`` that ended."""
        return self._clump_tracker().ended_rows

    def detach(self):
        super().detach()
        if self._clumps is not None:
            self._clumps.detach()

    def carry(self, history, fill=0.0, out=None, *, clumps=False):
        """A history array moved to this call's rows (:meth:`ContactIdentity.carry`);
        ``clumps=True`` for a history per clump pair."""
        if clumps:
            return self._clump_tracker().carry(history, fill, out)
        return super().carry(history, fill, out)
