"""examples/dem_hertz_mindlin.py carries the same tangential springs as a pure-Python DEM
step for 200 steps, and ``granularsap bench dem-loop`` runs against LAMMPS.

The reference finds its contacts by brute force (every pair of grains, every
wall plane, every triangle of the floor with the exact closest point) and
keeps each contact's spring in a dict keyed by ``(lower id, higher id)`` for
grain pairs and ``(id, wall, element)`` for wall contacts.  It runs in lock
step with the example: at every step it takes the example's state at the
force evaluation (after the kick and the drift), computes the forces with its
own springs, and both the springs (contact for contact) and the forces must
agree.  The grains are re-ordered every 50 steps, so the example's springs
only follow their contacts through the grains' ids.
"""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
EXAMPLE = ROOT / "examples" / "dem_hertz_mindlin.py"


def _load_example():
    name = "dem_hertz_mindlin_under_test"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, EXAMPLE)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name]


@pytest.fixture(scope="module")
def ex():
    return _load_example()


# ------------------------------------------------------------------ the reference


def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _sub(a, b):
    return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]


def _scale(s, a):
    return [s * a[0], s * a[1], s * a[2]]


def _cross(a, b):
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def _norm(a):
    return math.sqrt(_dot(a, a))


def _closest_on_triangle(p, a, b, c):
    """Closest point of triangle abc to p and its feature (0 face, 1 edge, 2 vertex)
    (Ericson, Real-Time Collision Detection, 5.1.5)."""
    ab, ac, ap = _sub(b, a), _sub(c, a), _sub(p, a)
    d1, d2 = _dot(ab, ap), _dot(ac, ap)
    if d1 <= 0 and d2 <= 0:
        return a, 2
    bp = _sub(p, b)
    d3, d4 = _dot(ab, bp), _dot(ac, bp)
    if d3 >= 0 and d4 <= d3:
        return b, 2
    vc = d1 * d4 - d3 * d2
    if vc <= 0 and d1 >= 0 and d3 <= 0:
        t = d1 / (d1 - d3)
        return [a[k] + t * ab[k] for k in range(3)], 1
    cp = _sub(p, c)
    d5, d6 = _dot(ab, cp), _dot(ac, cp)
    if d6 >= 0 and d5 <= d6:
        return c, 2
    vb = d5 * d2 - d1 * d6
    if vb <= 0 and d2 >= 0 and d6 <= 0:
        t = d2 / (d2 - d6)
        return [a[k] + t * ac[k] for k in range(3)], 1
    va = d3 * d6 - d5 * d4
    if va <= 0 and d4 - d3 >= 0 and d5 - d6 >= 0:
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return [b[k] + t * (c[k] - b[k]) for k in range(3)], 1
    den = 1.0 / (va + vb + vc)
    return [a[k] + ab[k] * vb * den + ac[k] * vc * den for k in range(3)], 0


def _law(mat, dt, n, delta, r_eff, m_eff, v_rel, spring):
    """Hertz-Mindlin of one contact, written out: (force on B, tangential force, spring)."""
    a = math.sqrt(r_eff * delta)
    v_n = _dot(v_rel, n)
    eta_n = mat.damping * m_eff * a
    e_eff = mat.young / (2.0 * (1.0 - mat.poisson ** 2))
    g_eff = mat.young / (4.0 * (2.0 - mat.poisson) * (1.0 + mat.poisson))
    f_n = max(4.0 / 3.0 * e_eff * a * delta - eta_n * v_n, 0.0)
    v_t = _sub(v_rel, _scale(v_n, n))
    length = _norm(spring)
    spring = _sub(spring, _scale(_dot(spring, n), n))
    turned = _norm(spring)
    spring = _scale(length / turned if turned > 0 else 0.0, spring)
    spring = [spring[k] + dt * v_t[k] for k in range(3)]
    k_t = 8.0 * g_eff * a
    eta_t = mat.tangential_damping * eta_n
    f_t = [-k_t * spring[k] - eta_t * v_t[k] for k in range(3)]
    size = _norm(f_t)
    cap = mat.friction * f_n
    if size > cap:
        f_t = _scale(cap / size, f_t)
        spring = [-(f_t[k] + eta_t * v_t[k]) / k_t for k in range(3)]
    return [f_n * n[k] + f_t[k] for k in range(3)], f_t, spring


def reference_forces(state, springs, wall_springs, planes, triangles, mat, dt, gravity):
    """Forces, torques and the springs of this step, brute force, springs in dicts.

    ``state``: (x, v, w, r, m, ids) as lists; ``planes``: [(point, normal)];
    ``triangles``: the floor's (f, 3, 3) corners; the floor is wall number
    ``len(planes)``.  Returns (force, torque, springs, wall_springs, floor
    contacts seen as (feature, count of triangles within reach)).
    """
    x, v, w, r, m, ids = state
    n = len(x)
    force = [_scale(m[i], gravity) for i in range(n)]
    torque = [[0.0, 0.0, 0.0] for _ in range(n)]
    new, new_wall, floor_seen = {}, {}, []
    for p in range(n):
        for q in range(p + 1, n):
            i, j = (p, q) if ids[p] < ids[q] else (q, p)      # A: the lower id
            d_vec = _sub(x[j], x[i])
            d = _norm(d_vec)
            if d > r[i] + r[j]:
                continue
            key = (ids[i], ids[j])
            delta = r[i] + r[j] - d
            nrm = _scale(1.0 / d, d_vec)
            arm_i, arm_j = r[i] - 0.5 * delta, r[j] - 0.5 * delta
            spin = [arm_i * w[i][k] + arm_j * w[j][k] for k in range(3)]
            v_rel = _sub(_sub(v[j], v[i]), _cross(spin, nrm))
            f, f_t, new[key] = _law(mat, dt, nrm, delta, r[i] * r[j] / (r[i] + r[j]),
                                    m[i] * m[j] / (m[i] + m[j]), v_rel,
                                    springs.get(key, [0.0, 0.0, 0.0]))
            t = _cross(nrm, f_t)
            for k in range(3):
                force[j][k] += f[k]
                force[i][k] -= f[k]
                torque[i][k] -= arm_i * t[k]
                torque[j][k] -= arm_j * t[k]

    def wall_contact(g, key, nrm, dist):
        v_rel = _sub(v[g], _scale(dist, _cross(w[g], nrm)))
        f, f_t, new_wall[key] = _law(mat, dt, nrm, r[g] - dist, r[g], m[g], v_rel,
                                     wall_springs.get(key, [0.0, 0.0, 0.0]))
        t = _cross(nrm, f_t)
        for k in range(3):
            force[g][k] += f[k]
            torque[g][k] -= dist * t[k]

    for g in range(n):
        for wall, (point, normal) in enumerate(planes):
            h = _dot(_sub(x[g], point), normal)
            if abs(h) <= r[g]:
                wall_contact(g, (ids[g], wall, 0), _scale(math.copysign(1.0, h), normal), abs(h))
        near = []
        for t, (a, b, c) in enumerate(triangles):
            q, feature = _closest_on_triangle(x[g], a, b, c)
            d = _norm(_sub(x[g], q))
            if d <= r[g]:
                near.append((d, t, feature, q))
        if near:
            # a flat floor: the one triangle under the centre is nearer than every
            # triangle touched at an edge or a vertex, which DEM codes drop
            d, t, feature, q = min(near)
            floor_seen.append((feature, len(near)))
            wall_contact(g, (ids[g], len(planes), t), _scale(1.0 / d, _sub(x[g], q)), d)
    return force, torque, new, new_wall, floor_seen


# ------------------------------------------------------------------------ the test


def _small_pour(ex, n, seed, n_threads, neighbor_list=False):
    """``n`` grains in a narrow column, shaken hard: many contacts begin, end and re-form."""
    rng = np.random.default_rng(seed)
    pos, _, radii, width = ex.initial_column(n, seed)
    vel = rng.normal(0.0, 15.0, (n, 3))
    omegas = rng.normal(0.0, 3.0, (n, 3))
    ids = rng.permutation(np.arange(100, 100 + 7 * n, 7))   # LAMMPS-like ids, not rows
    floor = ex.floor_mesh(width)
    pour = ex.Pour(pos, vel, radii, width, floor, n_threads=n_threads, ids=ids, omegas=omegas,
                   neighbor_list=neighbor_list)
    return pour, floor, rng


def _floor_triangles(floor):
    return np.asarray(floor.vertices, dtype=float)[np.asarray(floor.faces)]


@pytest.mark.parametrize("neighbor_list", [False, True], ids=["search", "list"])
@pytest.mark.parametrize("n_threads", [1, 2])
def test_springs_equal_pure_python_reference_for_200_steps(ex, n_threads, neighbor_list):
    """The example's springs equal a pure-Python reference's, its grains through a
    ContactSearch or (``neighbor_list``) a ContactList kept between rebuilds."""
    pour, floor, rng = _small_pour(ex, 50, 2, n_threads, neighbor_list)
    kept = 0
    w = pour.width   # the example's side walls: x = 0, x = w, y = 0, y = w, facing inwards
    planes = [([0.0, 0.0, 0.0], [1.0, 0.0, 0.0]), ([w, 0.0, 0.0], [-1.0, 0.0, 0.0]),
              ([0.0, 0.0, 0.0], [0.0, 1.0, 0.0]), ([0.0, w, 0.0], [0.0, -1.0, 0.0])]
    triangles = _floor_triangles(floor).tolist()
    gravity = list(map(float, ex.GRAVITY))
    springs, wall_springs = {}, {}
    # the example's first contact_forces ran in its constructor: replay it
    state0 = (pour.positions.tolist(), pour.velocities.tolist(), pour.omegas.tolist(),
              pour.radii.tolist(), pour.mass.tolist(), pour.ids.tolist())
    _, _, springs, wall_springs, _ = reference_forces(state0, {}, {}, planes, triangles,
                                                      pour.material, pour.dt, gravity)
    seen, ended, reformed, wall_keys, wall_ended = set(), set(), 0, set(), 0
    floor_features = set()
    for step in range(1, 201):
        if step % 50 == 0:
            pour.reorder(rng.permutation(len(pour.ids)))
        pour.kick()
        pour.positions += pour.dt * pour.velocities
        state = (pour.positions.tolist(), pour.velocities.tolist(), pour.omegas.tolist(),
                 pour.radii.tolist(), pour.mass.tolist(), pour.ids.tolist())
        force, torque, new, new_wall, floor_seen = reference_forces(
            state, springs, wall_springs, planes, triangles, pour.material, pour.dt, gravity)
        pour.force, pour.torque = pour.contact_forces()
        pour.kick()
        kept += neighbor_list and not pour.contacts.rebuilt

        # grain contacts: the same keys, the same springs
        ids = pour.ids
        lo = np.minimum(ids[pour.pairs[:, 0]], ids[pour.pairs[:, 1]])
        hi = np.maximum(ids[pour.pairs[:, 0]], ids[pour.pairs[:, 1]])
        got = {(int(a), int(b)): pour.spring[k] for k, (a, b) in enumerate(zip(lo, hi,
                                                                              strict=True))}
        assert set(got) == set(new), f"step {step}: contact sets differ"
        for key, value in new.items():
            np.testing.assert_allclose(got[key], value, rtol=1e-9, atol=1e-14,
                                       err_msg=f"step {step}, contact {key}")
        # wall contacts: (id, wall, element) and their springs
        c = pour.wall_contacts
        got_w = {(int(ids[s]), int(wl), int(e)): pour.wall_spring[k]
                 for k, (s, wl, e) in enumerate(zip(c.sphere, c.wall, c.element, strict=True))}
        assert set(got_w) == set(new_wall), f"step {step}: wall contact sets differ"
        for key, value in new_wall.items():
            np.testing.assert_allclose(got_w[key], value, rtol=1e-9, atol=1e-14,
                                       err_msg=f"step {step}, wall contact {key}")
        scale = max(float(np.abs(pour.force).max()), 1.0)
        np.testing.assert_allclose(pour.force, force, rtol=1e-9, atol=1e-12 * scale)
        np.testing.assert_allclose(pour.torque, torque, rtol=1e-9, atol=1e-12 * scale)

        # what the trajectory exercised: contacts that ended, and some that came back
        gone = set(springs) - set(new)
        reformed += len((set(new) - set(springs)) & ended)
        ended |= gone
        seen |= set(new)
        wall_ended += len(set(wall_springs) - set(new_wall))
        wall_keys |= set(new_wall)
        floor_features |= {f for f, _ in floor_seen}
        springs, wall_springs = new, new_wall

    assert len(seen) > 25 and len(ended) > 15, (len(seen), len(ended))
    assert reformed > 0, "no contact ended and re-formed: the test would not see it"
    assert wall_ended > 0 and any(k[1] == len(planes) for k in wall_keys)
    assert any(k[1] < len(planes) for k in wall_keys)
    assert floor_features == {0}   # on a flat floor, the contact kept is the face under it
    # springs that really slid and stuck: some large enough to matter
    assert max(np.abs(v).max() for v in springs.values()) > 1e-4
    if neighbor_list:  # the list was kept on some steps, and rebuilt on others
        assert 10 < kept < 190, kept


def test_floor_is_the_tiled_rectangle_written_as_stl(ex, tmp_path):
    path = tmp_path / "floor.stl"
    mesh = ex.floor_mesh(6.0, path)
    vertices, faces = ex.tiled_floor([-2 * ex.R_MAX, -2 * ex.R_MAX], [6.0 + 2 * ex.R_MAX] * 2,
                                     int(np.ceil((6.0 + 4 * ex.R_MAX) / (2 * ex.R_MAX))))
    assert path.read_text().startswith("solid floor")
    tri = _floor_triangles(mesh)
    expected = vertices[faces]
    assert tri.shape == expected.shape
    # the same triangles (the reader may merge vertices; corners keep their order)
    np.testing.assert_array_equal(tri, expected)


def test_spatial_order_keeps_springs(ex):
    """Re-ordering the rows between two steps changes nothing but the row order."""
    a, _, _ = _small_pour(ex, 30, 5, 1)
    b, _, _ = _small_pour(ex, 30, 5, 1)
    for _ in range(30):
        a.step()
        b.step()
    b.reorder(b.spatial_order())
    a.step()
    b.step()
    key_a = {tuple(sorted(a.ids[p])): s for p, s in zip(a.pairs, a.spring, strict=True)}
    key_b = {tuple(sorted(b.ids[p])): s for p, s in zip(b.pairs, b.spring, strict=True)}
    assert key_a.keys() == key_b.keys() and key_a
    for k in key_a:
        np.testing.assert_allclose(key_b[k], key_a[k], rtol=1e-12, atol=1e-15)


# ----------------------------------------------------------------- bench dem-loop


@pytest.mark.lammps
def test_dem_loop_runs_against_lammps(ex):
    pytest.importorskip("lammps_bridge")
    from granularsap.bench import demloop

    r = demloop.dem_loop(150, steps=8, settle=300, n_threads=1, example=ex)
    assert set(r["settings"]) == {"verlet", "list", "rebuild"}
    verlet, rebuild = r["settings"]["verlet"], r["settings"]["rebuild"]
    listed = r["settings"]["list"]
    for s in (verlet, listed, rebuild):
        g, lam = s["granularsap"], s["lammps"]
        assert 0 < g["min"] <= g["median"] and np.isfinite(g["mean"])
        assert 0 < g["walls_mean"] < g["mean"]
        assert g["grains_mean"] == pytest.approx(g["mean"] - g["walls_mean"])
        assert lam["pair"] > 0 and lam["modify"] > 0 and lam["neigh"] >= 0
        assert len(s["lammps_chunks"]) == len(g["chunk_means"]) == 8
        assert s["fastest_chunk"]["granularsap"] == min(g["chunk_means"])
        q = s["ratios"]
        assert 0 < q["all_neigh_modify_pair"] < q["all_neigh_modify"]
        # the two codes pour alike: after 300 steps from the same column, from the
        # same state, the same model: contact counts close
        assert g["contacts"] > 0 and abs(g["contacts"] - s["lammps_contacts"]) <= max(
            5, 0.1 * s["lammps_contacts"])
    # rebuilt every step: both codes build their list on each of the 8 steps (LAMMPS's
    # count runs on from the run's set-up, one build more); the Verlet list keeps it
    assert rebuild["granularsap"]["rebuilds"] == 8 and rebuild["lammps_builds"] >= 8
    assert verlet["granularsap"]["rebuilds"] < 8 and verlet["lammps_builds"] < 8
    # the neighbour list: LAMMPS's Verlet run, granularsap's ContactList, which
    # lists the contacts and more, and is rebuilt when a Verlet list is
    assert listed["lammps"] == verlet["lammps"]
    g = listed["granularsap"]
    assert g["rebuilds"] == verlet["granularsap"]["rebuilds"]
    # the grains' mean split into the steps that built the list and those that kept it
    for s in (verlet, listed, rebuild):
        h = s["granularsap"]
        assert h["grains_builds"] + h["grains_kept"] == pytest.approx(h["grains_mean"])
        assert (h["grains_kept"] == 0) == (h["rebuilds"] == 8)
        assert (h["grains_builds"] == 0) == (h["rebuilds"] == 0)
    assert g["listed"] >= g["contacts"] and g["separations_mean"] > 0
    assert rebuild["lammps"]["neigh"] > verlet["lammps"]["neigh"]
    assert 0 < rebuild["ratios"]["grains_neigh"] < rebuild["ratios"]["all_neigh"]
    # the single frame, as the bench's lammps-rebuild and granularsap-steady see it
    fr = r["frame"]
    assert fr["same_pairs"] and fr["granularsap_steady"]["pairs"] > 0
    assert 0 < fr["lammps_rebuild"]["neigh"] <= fr["lammps_rebuild"]["min"]
    text = demloop.format_result(r)
    assert "N=150" in text and " verlet: a kept Verlet list" in text
    assert " rebuild: rebuilt every step" in text and "grains / Neigh" in text
    assert " list: a kept neighbour list" in text and "listed pairs" in text
    if 0 < g["rebuilds"] < 8:
        assert "steps that built the list" in text and "LAMMPS's Other" in text
    assert "Neigh + Modify" in text and "fastest of 8 runs of 1 steps" in text
    assert "lammps-rebuild (Neigh + Comm of run 10" in text and "Modify holds" in text


@pytest.mark.lammps
def test_bench_cli_dem_loop(capsys, tmp_path):
    from granularsap.cli import main

    out = tmp_path / "dem.json"
    code = main(["bench", "dem-loop", "--sizes", "120", "--steps", "4", "--settle", "100",
                 "--threads", "1", "--json", str(out)])
    assert code == 0
    text = capsys.readouterr().out
    assert "dem-loop N=120" in text and "LAMMPS (its timers)" in text
    assert '"granularsap-bench-dem-loop/2"' in out.read_text()


def test_bench_cli_dem_loop_without_lammps(capsys):
    """--peers without a LAMMPS peer (or --exclude lammps) times granularsap alone."""
    from granularsap.cli import main

    code = main(["bench", "dem-loop", "--sizes", "100", "--steps", "3", "--settle", "50",
                 "--threads", "1", "--peers", "granularsap,granularsap-steady"])
    assert code == 0
    text = capsys.readouterr().out
    assert "dem-loop N=100: 3 steps from the column" in text
    assert "LAMMPS: not run (not asked for)" in text
    assert "LAMMPS (its timers)" not in text and "granularsap-steady" in text
    assert "lammps-rebuild (Neigh" not in text


def test_dem_loop_bad_arguments(tmp_path):
    import argparse

    from granularsap.bench import demloop
    from granularsap.bench.cli import add_arguments, run

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    with pytest.raises(ValueError, match="run 'dem-loop' on its own"):
        run(parser.parse_args(["dem-loop", "md-liquid"]))
    with pytest.raises(ValueError, match="--steps must be at least 1, got 0"):
        run(parser.parse_args(["dem-loop", "--steps", "0", "--sizes", "100"]))
    with pytest.raises(ValueError, match="--settle must be at least 0, got -1"):
        run(parser.parse_args(["dem-loop", "--settle", "-1", "--sizes", "100"]))
    with pytest.raises(FileNotFoundError, match="run it from a source checkout"):
        demloop.load_example(tmp_path / "missing.py")
