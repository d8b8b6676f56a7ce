"""ContactList: a neighbour list with a skin, kept between rebuilds.

Checked against a brute force of the agreed arithmetic on random walks (open,
periodic, triclinic, partly periodic; spheres inserted, deleted and re-ordered
by id): on every step the listed pairs that touch are exactly the contacts,
with the same distances and vectors bit for bit, and a history carried through
the rebuilds equals a dict keyed by the pair's ids and image shift.
"""

from __future__ import annotations

import numpy as np
import pytest

from granularsap import Cell, ContactList, ContactSearch

from .test_ties import brute

L = 6.0
CELLS = {
    "open": (None, np.eye(3) * 1e3, (False, False, False)),
    "periodic": (np.eye(3) * L, np.eye(3) * L, (True, True, True)),
    "triclinic": (np.array([[L, 0, 0], [1.3, L, 0], [-0.9, 0.7, L]]),
                  np.array([[L, 0, 0], [1.3, L, 0], [-0.9, 0.7, L]]), (True, True, True)),
    "slab": (np.eye(3) * L, np.eye(3) * L, (True, True, False)),
}


def _key(ida, idb, shift):
    """A pair by ids, the shift taken from the lower id to the higher."""
    s = tuple(int(v) for v in shift)
    if ida > idb:
        return (int(idb), int(ida), tuple(-v for v in s))
    return (int(ida), int(idb), s)


def walk(seed, steps, n0, *, step=0.03, churn_at=(), reorder_at=()):
    """Frames (positions, radii, ids): Gaussian steps, some spheres replaced by
    new ones (new ids) at the steps ``churn_at``, rows shuffled at ``reorder_at``."""
    rng = np.random.default_rng(seed)
    pos = rng.uniform(0, L, (n0, 3))
    rad = rng.uniform(0.2, 0.5, n0)
    ids = rng.permutation(10 * n0)[:n0] + 7
    next_id = 20 * n0
    frames = []
    for t in range(steps):
        if t in churn_at:
            keep = np.sort(rng.permutation(len(pos))[5:])
            new = rng.uniform(0, L, (7, 3))
            pos = np.concatenate([pos[keep], new])
            rad = np.concatenate([rad[keep], rng.uniform(0.2, 0.5, len(new))])
            ids = np.concatenate([ids[keep], np.arange(next_id, next_id + len(new))])
            next_id += len(new)
        if t in reorder_at:
            order = rng.permutation(len(pos))
            pos, rad, ids = pos[order], rad[order], ids[order]
        frames.append((pos.copy(), rad.copy(), ids.copy()))
        pos = pos + rng.normal(0.0, step, pos.shape)
    return frames


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("kind", list(CELLS))
def test_touching_pairs_are_the_contacts_and_history_follows_ids(kind, threads):
    box, cell, pbc = CELLS[kind]
    skin = 0.05
    frames = walk(11, 40, 160, churn_at=(17,), reorder_at=(29,))
    cl = ContactList(rebuild_margin=0.3, skin=skin, n_threads=threads)
    entered = {}  # oracle: pair key -> the step it came into the list
    history = np.empty(0)
    reasons = []
    for t, (x, r, ids) in enumerate(frames):
        kw = {} if box is None else {"box": box, "pbc": pbc}
        pairs, shifts = cl.update(x, r, ids=ids, **kw)
        reasons.append(cl.stats["reason"])
        d, vec = cl.separations(x)
        # the touching listed pairs are the contacts, bit for bit
        want = brute(x, cell, pbc, lambda i, j, r=r: (r[i] + r[j]) + skin)
        touch = d <= (r[pairs[:, 0]] + r[pairs[:, 1]]) + skin
        got = {(int(a), int(b), tuple(int(v) for v in s)): (dd, dv)
               for (a, b), s, dd, dv in zip(pairs[touch], shifts[touch], d[touch], vec[touch],
                                            strict=True)}
        assert got.keys() == want.keys(), f"step {t}"
        for k, (dd, dv) in want.items():
            assert got[k][0] == dd and np.array_equal(got[k][1], dv), (t, k)
        # history: the step each listed pair came into the list, carried
        keys = [_key(ids[a], ids[b], s) for (a, b), s in zip(pairs, shifts, strict=True)]
        assert len(set(keys)) == len(keys)
        history = cl.carry(history, fill=-1.0)
        history = np.where(history < 0, float(t), history)
        entered = {k: entered.get(k, t) for k in keys}
        np.testing.assert_array_equal(history, [entered[k] for k in keys])
        if not cl.rebuilt:
            np.testing.assert_array_equal(cl.previous_rows, np.arange(len(pairs)))
            assert len(cl.ended_rows) == 0
    # the list was kept on most steps and rebuilt when spheres moved, came or went
    assert reasons.count(None) >= 20, reasons
    assert reasons[0] == "first" and "moved" in reasons
    assert reasons[17] in ("count", "ids") and reasons[29] in ("radii", "ids")


def test_the_same_lists_on_one_and_two_threads():
    frames = walk(3, 15, 300)
    out = []
    for threads in (1, 2):
        cl = ContactList(rebuild_margin=0.2, n_threads=threads)
        out.append([tuple(np.concatenate([*cl.update(x, r, np.eye(3) * L, ids=ids),
                                          cl.separations(x)[1]], axis=1).ravel())
                    for x, r, ids in frames])
    assert out[0] == out[1]


def test_rebuilt_on_the_first_move_beyond_half_the_margin():
    x = np.array([[0.0, 0, 0], [2.3, 0, 0]])
    cl = ContactList(rebuild_margin=0.4)
    cl.update(x, 1.0)
    limit = 0.2 * (1 - 1e-9)  # less the rounding allowance, which is tiny here
    y = x.copy()
    y[1] += np.array([1.0, 1.0, 1.0]) / np.sqrt(3) * limit  # Euclidean, not per axis
    cl.update(y, 1.0)
    assert not cl.rebuilt
    y = x.copy()
    y[1, 0] += 0.2001
    cl.update(y, 1.0)
    assert cl.rebuilt and cl.stats["reason"] == "moved"


@pytest.mark.parametrize("change, reason", [
    ("radius", "radii"), ("count", "count"), ("ids", "ids"), ("labels", "clump_ids"),
    ("cell", "cell"), ("wrap", "moved"), ("nan", None)])
def test_what_rebuilds_the_list(change, reason):
    rng = np.random.default_rng(5)
    x = rng.uniform(0, L, (50, 3))
    r = np.full(50, 0.4)
    ids = np.arange(50) + 100
    labels = np.arange(50) // 2
    box = np.eye(3) * L
    cl = ContactList(rebuild_margin=0.2)
    cl.update(x, r, box, ids=ids, clump_ids=labels)
    # equal values in new arrays, a Cell of the same matrix: kept
    cl.update(x.copy(), r.copy(), box.copy(), ids=ids.copy(), clump_ids=labels.copy())
    assert not cl.rebuilt
    cl.update(x, r, Cell.from_matrix(box), ids=ids, clump_ids=labels)
    assert cl.rebuilt and cl.stats["reason"] == "cell"  # a Cell is compared as a Cell
    cl.update(x, r, Cell.from_matrix(box), ids=ids, clump_ids=labels)
    assert not cl.rebuilt
    args = dict(positions=x, radii=r, box=Cell.from_matrix(box), ids=ids, clump_ids=labels)
    if change == "radius":
        args["radii"] = np.where(np.arange(50) == 7, 0.41, r)
    elif change == "count":
        args.update(positions=x[:-1], radii=r[:-1], ids=ids[:-1], clump_ids=labels[:-1])
    elif change == "ids":
        args["ids"] = ids[::-1].copy()
    elif change == "labels":
        args["clump_ids"] = np.arange(50)
    elif change == "cell":
        args["box"] = np.eye(3) * (L + 0.01)
    elif change == "wrap":  # a sphere put back into the cell by a cell vector
        y = x.copy()
        y[3, 0] += L
        args["positions"] = y
    else:
        y = x.copy()
        y[4, 1] = np.nan
        with pytest.raises(ValueError, match="positions must be finite.*row 4"):
            cl.update(y, r, args["box"], ids=ids, clump_ids=labels)
        return
    before = cl.stats["builds"]
    cl.update(args.pop("positions"), args.pop("radii"), args.pop("box"), **args)
    assert cl.rebuilt and cl.stats["reason"] == reason
    assert cl.stats["builds"] == before + 1



@pytest.mark.parametrize("change, reason", [
    ("radius", "radii"), ("ids", "ids"), ("moved", "moved"),
    ("in place", "moved"), ("float32", "moved"), ("nan", None)])
def test_what_rebuilds_a_list_of_plain_arrays(change, reason):
    # float64 and int64 arrays without a cell or labels: one kernel call decides
    rng = np.random.default_rng(6)
    x = rng.uniform(0, L, (60, 3))
    r = np.full(60, 0.4)
    ids = np.arange(60) + 100
    cl = ContactList(rebuild_margin=0.2)
    cl.update(x, r, ids=ids)
    cl.update(x.copy(), r.copy(), ids=ids.copy())
    assert not cl.rebuilt and cl.stats["reason"] is None
    y, rr, ii = x.copy(), r.copy(), ids.copy()
    if change == "radius":
        rr[7] = 0.41
    elif change == "ids":
        ii[[3, 4]] = ii[[4, 3]]
    elif change == "moved":
        y[9, 2] += 0.1001
    elif change == "in place":  # the list keeps a copy of the positions it was built on
        x[9, 2] += 0.1001
        y = x
    elif change == "float32":  # another dtype takes the checks, with the same answer
        y = (x + np.float32(0.25)).astype(np.float32)
    else:
        y[4, 1] = np.nan
        with pytest.raises(ValueError, match="positions must be finite.*row 4"):
            cl.update(y, rr, ids=ii)
        return
    cl.update(y, rr, ids=ii)
    assert cl.rebuilt and cl.stats["reason"] == reason
    cl.update(y, rr, ids=ii)
    assert not cl.rebuilt


def test_results_survive_the_next_call():
    frames = walk(8, 30, 200, step=0.05)
    cl = ContactList(rebuild_margin=0.2)
    held = None
    for x, r, ids in frames:
        pairs, shifts = cl.update(x, r, np.eye(3) * L, ids=ids)
        d, vec = cl.separations(x)
        if held is not None:
            for arr, copy in zip(held[0], held[1], strict=True):
                np.testing.assert_array_equal(arr, copy)
        now = (pairs, shifts, d, vec)
        held = (now, [a.copy() for a in now])
    assert cl.stats["builds"] > 1


def test_errors_name_the_argument():
    for bad in (0.0, -0.1, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="rebuild_margin"):
            ContactList(rebuild_margin=bad)
    with pytest.raises(TypeError, match="rebuild_margin"):
        ContactList(rebuild_margin="0.2")
    with pytest.raises(ValueError, match="skin"):
        ContactList(rebuild_margin=0.2, skin=-1.0)
    with pytest.raises(ValueError, match="periodic_images"):
        ContactList(rebuild_margin=0.2, periodic_images="some")
    # a range beyond half the cell, once the margin is added: the message says so
    x3 = np.random.default_rng(0).uniform(0, 3, (20, 3))
    with pytest.raises(ValueError, match=r"2 \* max\(radii\) \+ skin \+ rebuild_margin "
                                         r"1\.59.* exceeds half"):
        ContactList(rebuild_margin=0.2).update(x3, 0.7, [3, 3, 3, 90, 90, 90])
    cl = ContactList(rebuild_margin=0.2)
    with pytest.raises(RuntimeError, match="call update first"):
        cl.separations(np.zeros((2, 3)))
    x = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    with pytest.raises(ValueError, match="radii"):
        cl.update(x, [-1.0, 1.0])
    cl.update(x, 1.0)
    with pytest.raises(ValueError, match="positions must have the 2 rows"):
        cl.separations(np.zeros((3, 3)))
    with pytest.raises(ValueError, match="history must have one row per pair"):
        cl.update(x, 1.0)
        cl.carry(np.zeros(5))


def test_a_rebuild_carries_as_the_building_search_does():
    """After a rebuild, ``carry`` is ContactSearch.carry of a search whose skin
    holds the margin: the same rows for the same frames."""
    frames = walk(21, 12, 120, step=0.12, churn_at=(6,))
    cl = ContactList(rebuild_margin=0.25, skin=0.1)
    ref = ContactSearch(skin=0.1 + 0.25, quantities="PS", identity=True)
    for x, r, ids in frames:
        pairs, shifts = cl.update(x, r, np.eye(3) * L, ids=ids)
        if cl.rebuilt:
            p2, s2 = ref.update(x, r, np.eye(3) * L, ids=ids)
            np.testing.assert_array_equal(pairs, p2)
            np.testing.assert_array_equal(shifts, s2)
            np.testing.assert_array_equal(cl.previous_rows, ref.previous_rows)
            np.testing.assert_array_equal(cl.ended_rows, ref.ended_rows)


@pytest.mark.parametrize("scale", [1e-300, 1e-160, 1e200, 2.0**-1000])
def test_any_magnitude_gives_the_contacts_of_a_search(scale):
    """Positions, radii and margin of any magnitude: the touching listed pairs are
    ContactSearch's contacts with the same d, D and shifts, bit for bit (squares
    that would underflow or overflow are taken row by row in their own power of
    two, as the searches do), and the list is kept between rebuilds."""
    frames = walk(4, 12, 120, step=0.03)
    cl = ContactList(rebuild_margin=0.3 * scale)
    kept = 0
    for x, r, ids in frames:
        x, r = x * scale, r * scale
        pairs, shifts = cl.update(x, r, ids=ids)
        kept += not cl.rebuilt
        d, vec = cl.separations(x)
        touch = d <= r[pairs[:, 0]] + r[pairs[:, 1]]
        p2, d2, v2, s2 = ContactSearch(quantities="PdDS").update(x, r)
        got = sorted(zip(map(tuple, pairs[touch].tolist()), d[touch].tolist(),
                         map(tuple, vec[touch].tolist()), strict=True))
        want = sorted(zip(map(tuple, p2.tolist()), d2.tolist(), map(tuple, v2.tolist()),
                          strict=True))
        assert got == want
    assert kept >= 5
