"""Acceleration structures (impl.accel): every structure returns brute force's
closest hit (primitive id, and t within 1e-6 relative) and any-hit answer on
random rays through random scenes of spheres and triangles, in float64 and
float32, including rays starting inside the scene, axis-parallel rays, rays
with zero (and −0.0) direction components and rays aimed at shared mesh
vertices (ties); the trees and the grid are well formed; the ray tracers'
images do not change with the structure."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from gibench import registry
from core.loader import load_scene
from impl import accel
from impl.accel.bvh import build_bvh
from impl.accel.goldsmith_salmon import build_goldsmith_salmon
from impl.accel.grid import build_grid
from impl.accel.octree import build_octree
from impl.accel.primitives import prim_bounds
from impl.accel.slabs import slab_normals
from impl.rays import RayConfig, ray_config
from impl.scene_arrays import flatten

SUITES = Path(__file__).resolve().parent.parent / "suites"
STRUCTURES = [a for a in accel.ACCELS if a != "none"]
SEED = 20261123


def random_scene(rng, n_spheres, n_tris):
    """Spheres of radius 0.01–0.15 and triangles of size ~0.2 in [-1, 1]³, plus a
    tessellated axis-aligned floor (shared edges and vertices: exact ties)."""
    c = rng.uniform(-1, 1, (n_spheres, 3))
    r = rng.uniform(0.01, 0.15, n_spheres)
    v = rng.uniform(-1, 1, (n_tris, 1, 3)) + rng.normal(0, 0.1, (n_tris, 3, 3))
    g = np.linspace(-1, 1, 5)
    quads = []
    for i in range(4):
        for j in range(4):
            a, b = [g[i], -1.0, g[j]], [g[i + 1], -1.0, g[j]]
            cc, d = [g[i + 1], -1.0, g[j + 1]], [g[i], -1.0, g[j + 1]]
            quads += [[a, b, cc], [a, cc, d]]
    v = np.concatenate([v, np.array(quads)])
    shape = np.concatenate([np.arange(n_spheres), n_spheres + np.arange(len(v)) // 7])
    return c, r, v, shape


def random_rays(rng, n):
    """Origins outside and inside the scene box; random, axis-parallel, zero-component
    directions (±0.0), and rays through the floor's shared vertices."""
    o = rng.uniform(-2, 2, (n, 3))
    o[: n // 4] = rng.uniform(-0.9, 0.9, (n // 4, 3))          # inside the scene bounds
    d = rng.normal(size=(n, 3))
    k = n // 8
    axes = rng.integers(0, 3, k)
    d[k:2 * k] = 0.0
    d[k + np.arange(k), axes] = rng.choice([-1.0, 1.0], k)     # axis-parallel
    zero = rng.integers(0, 3, k)
    d[2 * k + np.arange(k), zero] = rng.choice([0.0, -0.0], k)  # one zero component
    d[3 * k:4 * k, :2] = rng.choice([0.0, -0.0], (k, 2))        # two zero components
    d[3 * k:4 * k, 2] = rng.choice([-1.0, 1.0], k)
    # Through the floor's grid vertices (-1 + 0.5 i, -1, -1 + 0.5 j): edges shared by 2–6 triangles.
    gv = np.stack([-1 + 0.5 * rng.integers(1, 4, k), np.full(k, -1.0), -1 + 0.5 * rng.integers(1, 4, k)], 1)
    o[4 * k:5 * k] = gv + rng.uniform(-1, 1, (k, 3)) * [1, 0, 1] + [0, 1.5, 0]
    d[4 * k:5 * k] = gv - o[4 * k:5 * k]
    # Origins exactly on the scene box's planes.
    o[5 * k:6 * k, rng.integers(0, 3)] = -1.0
    d /= np.linalg.norm(d, axis=1)[:, None]
    return o, d


def config(c, r, v, shape, name, dtype, form=2, **kw):
    c, r, v = (np.ascontiguousarray(x, dtype=dtype) for x in (c, r, v))
    return RayConfig(form, 2, 1e-4, 1e-9, 1e-7, c, r, v, *accel.build(name, c, r, v, shape, **kw))


@pytest.mark.parametrize("dtype", [np.float64, np.float32], ids=["float64", "float32"])
@pytest.mark.parametrize("seed", [SEED, SEED + 1])
def test_every_structure_returns_the_brute_force_closest_hit(dtype, seed):
    rng = np.random.default_rng(seed)
    c, r, v, shape = random_scene(rng, 150, 150)
    o, d = random_rays(rng, 4000)
    t0, p0, b0, _ = accel.trace_batch(config(c, r, v, shape, "none", dtype), o, d)
    assert (p0 >= 0).mean() > 0.3, "too few hits to test anything"
    hit = p0 >= 0
    for name in STRUCTURES:
        t, p, b, counts = accel.trace_batch(config(c, r, v, shape, name, dtype), o, d)
        bad = np.flatnonzero(p != p0)
        assert len(bad) == 0, (f"{name} {dtype.__name__} seed={seed}: primitive differs on "
                               f"{len(bad)} rays, first o={o[bad[0]].tolist()} d={d[bad[0]].tolist()}: "
                               f"{p[bad[0]]} at t={t[bad[0]]} vs brute force {p0[bad[0]]} at t={t0[bad[0]]}")
        np.testing.assert_allclose(t[hit], t0[hit], rtol=1e-6, err_msg=f"{name} seed={seed}")
        np.testing.assert_array_equal(b[hit], b0[hit], err_msg=f"{name}: barycentrics")
        assert (counts[:, 1] >= 0).all()


@pytest.mark.parametrize("dtype", [np.float64, np.float32], ids=["float64", "float32"])
def test_every_structure_answers_shadow_rays_as_brute_force(dtype):
    """Any-hit within (tmin, tmax): segments ending before, at and after the first hit."""
    rng = np.random.default_rng(SEED + 7)
    c, r, v, shape = random_scene(rng, 120, 120)
    o, d = random_rays(rng, 3000)
    t0, p0, _, _ = accel.trace_batch(config(c, r, v, shape, "none", dtype), o, d)
    tmax = np.where(p0 >= 0, t0, 3.0) * rng.choice([0.5, 0.999, 1.001, 2.0], len(o))
    tmin = rng.choice([0.0, 0.05], len(o))
    want, _ = accel.occluded_batch(config(c, r, v, shape, "none", dtype), o, d, tmin, tmax)
    assert 0.1 < want.mean() < 0.9, "the shadow rays should be partly blocked"
    for name in STRUCTURES:
        got, _ = accel.occluded_batch(config(c, r, v, shape, name, dtype), o, d, tmin, tmax)
        bad = np.flatnonzero(got != want)
        assert len(bad) == 0, f"{name} {dtype.__name__}: any-hit differs on {len(bad)} rays (first {bad[:5]})"


@pytest.mark.parametrize("form", [0, 1], ids=["algebraic", "geometric"])
def test_the_structures_keep_the_configured_sphere_form(form):
    """With the algebraic / geometric sphere test the hits still equal brute force's."""
    rng = np.random.default_rng(SEED + 3)
    c, r, v, shape = random_scene(rng, 200, 0)
    o, d = random_rays(rng, 2000)
    t0, p0, _, _ = accel.trace_batch(config(c, r, v, shape, "none", np.float32, form), o, d)
    for name in ("bvh-sah", "grid", "slabs", "bvh-wide"):
        t, p, _, _ = accel.trace_batch(config(c, r, v, shape, name, np.float32, form), o, d)
        np.testing.assert_array_equal(p, p0, err_msg=name)
        np.testing.assert_array_equal(t, t0, err_msg=name)


def test_hierarchies_cost_fewer_tests_than_brute_force():
    """Tests per ray: ~log n nodes and a handful of primitives for 3000 spheres (brute force 3000)."""
    rng = np.random.default_rng(SEED + 5)
    c = rng.uniform(-1, 1, (3000, 3))
    r = np.full(3000, 0.01)
    v = np.empty((0, 3, 3))
    o, d = random_rays(rng, 2000)
    _, p0, _, _ = accel.trace_batch(config(c, r, v, None, "none", np.float64), o, d)
    for name in ("bvh-median", "bvh-sah", "bvh-gs", "grid", "octree", "bvh-wide"):
        _, p, _, counts = accel.trace_batch(config(c, r, v, None, name, np.float64), o, d)
        np.testing.assert_array_equal(p, p0)
        assert counts[:, 1].mean() < 30, f"{name}: {counts[:, 1].mean():.1f} primitive tests per ray"
        assert counts[:, 0].mean() < 300, f"{name}: {counts[:, 0].mean():.1f} nodes per ray"
    _, _, _, counts = accel.trace_batch(config(c, r, v, None, "bv", np.float64), o, d)
    assert (counts[:, 0] == 3000).all(), "per-object volumes: every volume tested (n·B)"


@pytest.mark.parametrize("builder", [lambda lo, hi: build_bvh(lo, hi, "median"),
                                     lambda lo, hi: build_bvh(lo, hi, "sah"),
                                     build_goldsmith_salmon, build_octree],
                         ids=["median", "sah", "goldsmith-salmon", "octree"])
def test_trees_are_well_formed(builder):
    """Every primitive sits in a leaf whose box (and every ancestor's) contains its bounds;
    BVHs hold each primitive exactly once."""
    rng = np.random.default_rng(SEED + 11)
    c, r, v, _ = random_scene(rng, 300, 300)
    lo, hi = prim_bounds(c, r, v)
    nlo, nhi, na, nb, idx = builder(lo, hi)
    seen = np.zeros(len(lo), dtype=int)
    stack = [(0, None)]
    while stack:
        n, parent = stack.pop()
        if parent is not None and builder is not build_octree:
            assert (nlo[n] >= nlo[parent]).all() and (nhi[n] <= nhi[parent]).all()
        if nb[n] >= 0:
            prims = idx[na[n]:na[n] + nb[n]]
            seen[prims] += 1
            if builder is not build_octree:
                assert (lo[prims] >= nlo[n]).all() and (hi[prims] <= nhi[n]).all()
        else:
            assert na[n] > n, "children must follow their parent"
            stack += [(k, n) for k in range(na[n], na[n] - nb[n])]
    if builder is build_octree:
        assert (seen >= 1).all()
    else:
        np.testing.assert_array_equal(seen, 1)


def test_wide_bvh_is_the_sah_tree_collapsed_with_outward_float32_boxes():
    """Each primitive in exactly one leaf; every slot's float32 box contains the float64
    bounds of every primitive below it; ≤ WIDTH children per node, each node's slots
    used before empty ones are filled with empty boxes; fewer nodes than the binary tree."""
    from impl.accel.wide import WIDTH, collapse

    rng = np.random.default_rng(SEED + 17)
    c, r, v, _ = random_scene(rng, 400, 400)
    lo, hi = prim_bounds(c, r, v)
    nlo, nhi, na, nb, idx = build_bvh(lo, hi, "sah")
    box, sa, sb = collapse(nlo, nhi, na, nb)
    assert box.dtype == np.float32 and box.shape[1:] == (6, WIDTH)
    M = len(box)
    assert M < (nb < 0).sum(), "collapsing must remove interior nodes"
    seen = np.zeros(len(lo), dtype=int)

    def below(slot):
        if sb[slot] >= 0:
            return idx[sa[slot]:sa[slot] + sb[slot]]
        n = sa[slot]
        assert n > slot // WIDTH, "children must follow their parent"
        return np.concatenate([below(n * WIDTH + k) for k in range(WIDTH)])

    for n in range(M):
        for k in range(WIDTH):
            s = n * WIDTH + k
            if sb[s] == 0:
                assert np.isinf(box[n, :3, k]).all() and (box[n, :3, k] > 0).all()
                continue
            if sb[s] > 0:
                seen[idx[sa[s]:sa[s] + sb[s]]] += 1
            prims = below(s)
            assert (box[n, :3, k].astype(np.float64) <= lo[prims]).all()
            assert (box[n, 3:, k].astype(np.float64) >= hi[prims]).all()
    np.testing.assert_array_equal(seen, 1)


@pytest.mark.parametrize("dtype", [np.float64, np.float32], ids=["float64", "float32"])
def test_ulp_above_is_nextafter_toward_inf_bit_for_bit(dtype):
    """The inline ``ulp_above`` (integer arithmetic on the bits) equals
    ``np.nextafter(t, inf)``: signed zeros, subnormals, the largest finite
    numbers, ±inf, NaN and random magnitudes over the whole exponent range."""
    from numba import njit

    from impl.accel.primitives import ulp_above

    @njit
    def kernel(a, out):
        for i in range(a.shape[0]):
            out[i] = ulp_above(a[i])

    fi = np.finfo(dtype)
    special = [0.0, -0.0, 1.0, -1.0, np.inf, -np.inf, np.nan, fi.max, -fi.max, fi.tiny,
               -fi.tiny, fi.smallest_subnormal, -fi.smallest_subnormal]
    rng = np.random.default_rng(SEED + 23)
    mags = 2.0 ** rng.uniform(np.log2(fi.smallest_subnormal), np.log2(fi.max), 20000)
    a = np.concatenate([np.array(special, dtype=dtype),
                        (rng.choice([-1.0, 1.0], 20000) * mags).astype(dtype)])
    out = np.empty_like(a)
    kernel(a, out)
    with np.errstate(over="ignore"):
        ref = np.nextafter(a, dtype(np.inf))
    ints = np.int64 if dtype == np.float64 else np.int32
    np.testing.assert_array_equal(out.view(ints), ref.view(ints))


def test_wide_bvh_node_records_hold_the_boxes_and_child_references():
    """``wide_arrays`` stores each node as one record of 8·WIDTH float32 words: the
    collapsed boxes bit for bit, then per child its int32 reference (the child node,
    or ``-s - 1`` for the leaf or empty slot s), then zero padding."""
    from impl.accel.wide import WIDTH, collapse, wide_arrays

    rng = np.random.default_rng(SEED + 19)
    c, r, v, _ = random_scene(rng, 150, 150)
    lo, hi = prim_bounds(c, r, v)
    nlo, nhi, na, nb, idx = build_bvh(lo, hi, "sah")
    box, sa, sb = collapse(nlo, nhi, na, nb)
    acc_f, acc_i = wide_arrays(box, sa, sb, idx, c, r, v)
    M = len(box)
    rec = acc_f.view(np.float32)[:M * 8 * WIDTH].reshape(M, 8, WIDTH)
    np.testing.assert_array_equal(rec[:, :6, :], box)
    ref = rec[:, 6, :].view(np.int32).reshape(-1)
    s = np.arange(M * WIDTH)
    np.testing.assert_array_equal(ref, np.where(sb < 0, sa, -s - 1))
    assert (ref[sb < 0] > 0).all(), "interior children are nodes after the root"
    np.testing.assert_array_equal(rec[:, 7, :], 0.0)
    assert acc_i[1] == M * 8 * WIDTH // 2, "the leaf groups start after the records"


@pytest.mark.parametrize("dtype", [np.float64, np.float32], ids=["float64", "float32"])
def test_wide_batches_and_packets_return_brute_force_answers(dtype):
    """The wavefront entry points over SoA rays — single rays, and packets of 8 and 64
    consecutive rays (coherent camera rays and incoherent random rays, so the packets
    both stay together and fall back to single rays) — give brute force's closest hit
    (id, t, barycentrics) and any-hit answer."""
    from impl.accel.wide import (wide_closest_batch, wide_closest_packets, wide_occluded_batch,
                                 wide_occluded_packets)

    rng = np.random.default_rng(SEED + 19)
    c, r, v, shape = random_scene(rng, 300, 300)
    o1, d1 = random_rays(rng, 1500)
    gy, gx = np.mgrid[-1:1:40j, -1:1:40j]                      # a pinhole camera's rays
    d2 = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, -2.0)], 1)
    d2 /= np.linalg.norm(d2, axis=1)[:, None]
    o = np.concatenate([np.broadcast_to([0.0, 0.0, 3.0], d2.shape), o1])
    d = np.concatenate([d2, d1])
    n = len(o)
    R0 = config(c, r, v, shape, "none", dtype)
    R = config(c, r, v, shape, "bvh-wide", dtype)
    t0, p0, b0, _ = accel.trace_batch(R0, o, d)
    assert (p0 >= 0).mean() > 0.3
    cols = [np.ascontiguousarray(x) for x in (*o.T, *d.T)]
    tmin, tmax = np.zeros(n), np.full(n, np.inf)
    runs = {"batch": lambda *out: wide_closest_batch(R, *cols, tmin, tmax, *out)}
    for size in (8, 64):
        runs[f"packets{size}"] = lambda *out, size=size: wide_closest_packets(R, *cols, tmin, tmax, *out, size)
    for label, run in runs.items():
        t, p, b1, b2 = np.empty(n), np.empty(n, dtype=np.int64), np.empty(n), np.empty(n)
        run(t, p, b1, b2)
        np.testing.assert_array_equal(p, p0, err_msg=label)
        np.testing.assert_array_equal(t, t0, err_msg=label)
        np.testing.assert_array_equal(np.stack([b1, b2], 1), b0, err_msg=label)
    s_max = np.where(p0 >= 0, t0, 3.0) * rng.choice([0.5, 0.999, 1.001, 2.0], n)
    s_min = rng.choice([0.0, 0.05], n)
    want, _ = accel.occluded_batch(R0, o, d, s_min, s_max)
    assert 0.1 < want.mean() < 0.9
    got = np.empty(n, dtype=np.bool_)
    wide_occluded_batch(R, *cols, s_min, s_max, got)
    np.testing.assert_array_equal(got, want)
    for size in (8, 64):
        got[:] = False
        wide_occluded_packets(R, *cols, s_min, s_max, got, size)
        np.testing.assert_array_equal(got, want, err_msg=f"packets of {size}")


@pytest.mark.parametrize("dtype", [np.float64, np.float32], ids=["float64", "float32"])
def test_sphere_lanes_equal_the_scalar_stable_test_bit_for_bit(dtype):
    """The wide BVH's vector sphere test (four spheres a call) returns, lane by lane, the
    scalar stable test's t bit for bit and its hit (t > 0) on the cases where its
    branches decide: rays through the centre, grazing the silhouette (the
    discriminant's sign decided by rounding), starting inside, on and behind the
    sphere, small spheres far from the origin (the cancellation the stable form
    avoids), limits cutting between the roots; a NaN-centre padding lane misses."""
    from numba import njit

    from impl.accel.wide import LANES, _sph_lanes
    from impl.intersect import ray_sphere_stable

    @njit
    def lanes(data, o, d, tmin, tmax, out_t, out_m):
        tn = np.empty(LANES)
        for i in range(o.shape[0]):
            for g in range(data.shape[0] // (4 * LANES)):
                m = _sph_lanes(data, g * 4 * LANES, o[i, 0], o[i, 1], o[i, 2], d[i, 0], d[i, 1],
                               d[i, 2], tmin[i], tmax[i], tn)
                for k in range(LANES):
                    out_t[i, g * LANES + k] = tn[k]
                    out_m[i, g * LANES + k] = (m >> k) & 1

    @njit
    def scalar(c, r, o, d, tmin, tmax, out_t):
        for i in range(o.shape[0]):
            for j in range(r.shape[0]):
                out_t[i, j] = ray_sphere_stable(o[i, 0], o[i, 1], o[i, 2], d[i, 0], d[i, 1], d[i, 2],
                                                c[j, 0], c[j, 1], c[j, 2], r[j], tmin[i], tmax[i])

    rng = np.random.default_rng(SEED + 23)
    ns = 4 * LANES
    c = np.concatenate([rng.uniform(-1, 1, (ns - 3, 3)), [[0.0, 0.0, 0.0], [1e4, 0.0, 0.0],
                                                          [0.0, -3e3, 2.0]]])
    r = np.concatenate([rng.uniform(0.05, 0.8, ns - 3), [1.0, 1e-2, 0.5]])
    n = 3000
    o = rng.uniform(-3, 3, (n, 3))
    o[:300] = c[rng.integers(0, ns, 300)]                              # from the centres
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    j = rng.integers(0, ns, n)
    aim = c[j] - o
    aim = np.where(np.linalg.norm(aim, axis=1)[:, None] > 0, aim, u)     # from that very centre
    q = rng.integers(0, 3, n)                                          # at a centre, a silhouette, anywhere
    side = np.cross(aim, u)
    side /= np.linalg.norm(side, axis=1)[:, None] + 1e-300
    aim = np.where(q[:, None] == 1, aim + side * r[j][:, None] * rng.uniform(0.999, 1.001, (n, 1)), aim)
    d = np.where(q[:, None] == 2, u, aim)
    d /= np.linalg.norm(d, axis=1)[:, None]
    o[300:400] = c[j[300:400]] + 0.5 * r[j[300:400]][:, None] * u[300:400]     # inside
    o[400:500] = c[j[400:500]] + r[j[400:500]][:, None] * u[400:500]           # on the surface
    tmin = rng.choice([0.0, 1e-4, 0.5], n)
    tmax = rng.choice([np.inf, 1.0, 3.0], n)
    c, r, o, d, tmin, tmax = (np.asarray(x, dtype) for x in (c, r, o, d, tmin, tmax))
    data = np.zeros((ns // LANES, 4, LANES), dtype)
    data[:, :3, :] = c.reshape(ns // LANES, LANES, 3).transpose(0, 2, 1)
    data[:, 3, :] = r.reshape(ns // LANES, LANES)
    want = np.empty((n, ns), dtype)
    scalar(c, r, o, d, tmin, tmax, want)
    got_t, got_m = np.empty((n, ns)), np.empty((n, ns), np.int64)
    lanes(data.reshape(-1), o, d, tmin, tmax, got_t, got_m)
    hit = want > 0
    aimed = hit[np.arange(n), j]
    graze = q[500:] == 1
    assert hit.sum() > 2000 and (want == -1).any() and (want[hit] < 0.5).any()
    assert 0.2 < aimed[500:][graze].mean() < 0.8, "the silhouette rays should split into hits and misses"
    np.testing.assert_array_equal(got_m, hit)
    np.testing.assert_array_equal(got_t[hit], want[hit].astype(np.float64))
    pad = np.zeros((1, 4, LANES), dtype)
    pad[0, :3, :] = np.nan
    pad_t, pad_m = np.empty((n, LANES)), np.empty((n, LANES), np.int64)
    lanes(pad.reshape(-1), o, d, tmin, tmax, pad_t, pad_m)
    assert not pad_m.any()


def test_grid_lists_every_primitive_in_every_voxel_its_box_overlaps():
    rng = np.random.default_rng(SEED + 13)
    c, r, v, _ = random_scene(rng, 100, 100)
    lo, hi = prim_bounds(c, r, v)
    glo, ghi, cs, ints, off, refs = build_grid(lo, hi)
    res = ints[:3]
    assert res.prod() >= len(lo) and (res >= 1).all()
    for p in rng.choice(len(lo), 40, replace=False):
        i0 = np.clip(np.floor((lo[p] - glo[0]) / cs).astype(int), 0, res - 1)
        i1 = np.clip(np.floor((hi[p] - glo[0]) / cs).astype(int), 0, res - 1)
        for z in range(i0[2], i1[2] + 1):
            for y in range(i0[1], i1[1] + 1):
                for x in range(i0[0], i1[0] + 1):
                    cell = (z * res[1] + y) * res[0] + x
                    assert p in refs[off[cell]:off[cell + 1]]
    assert len(refs) >= len(lo)


def test_slab_normals_are_unit_and_distinct():
    for k in (3, 7, 13):
        n = slab_normals(k)
        assert n.shape == (k, 3)
        np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0)
        assert np.linalg.matrix_rank(n) == 3 and len(np.unique(np.abs(n @ n.T).round(9), axis=0)) == k
    with pytest.raises(ValueError, match="slab_normals must be one of"):
        slab_normals(5)


def test_more_slab_normals_cull_more_objects():
    """Seven normals bound a rotated mesh object more tightly than three: fewer primitive tests."""
    rng = np.random.default_rng(SEED + 17)
    c, r, v, shape = random_scene(rng, 0, 400)
    o, d = random_rays(rng, 3000)
    tests = {}
    for k in (3, 7):
        _, p, _, counts = accel.trace_batch(config(c, r, v, shape, "slabs", np.float64, slab_normals=k), o, d)
        tests[k] = counts[:, 1].mean()
    assert tests[7] < tests[3], tests


def test_unknown_structure_is_refused_with_the_valid_names():
    with pytest.raises(ValueError, match="unknown structure 'kd'.*bvh-sah"):
        accel.build("kd", np.zeros((1, 3)), np.ones(1), np.empty((0, 3, 3)))
    with pytest.raises(registry.ParamError, match="accel"):
        registry.get("whitted").parse_params({"accel": "bsp"})


def test_empty_scene_misses_with_every_structure():
    scene = load_scene(SUITES / "spheres" / "lit_sphere.xml")
    A = flatten(scene)._replace(sph_center=np.empty((0, 3)), sph_radius=np.empty(0),
                                tri_v=np.empty((0, 3, 3)), prim_shape=np.empty(0, dtype=np.int64))
    for name in accel.ACCELS:
        R = ray_config(A, registry.get("whitted").parse_params({"accel": name}), algorithm="whitted")
        _, p, _, _ = accel.trace_batch(R, np.zeros((4, 3)), np.eye(4, 3) + [0, 0, 1e-3])
        assert (p == -1).all()


# ------------------------------------------------------------ render level ---

def small(path, width, height):
    sc = load_scene(path)
    return replace(sc, camera=replace(sc.camera, film=replace(sc.camera.film, width=width, height=height)))


@pytest.mark.parametrize("scene", ["cornell/cornell_mirror_glass.xml", "spheres/sphere_grid.xml",
                                   "spheres/meshes.xml"])
def test_whitted_images_do_not_depend_on_the_structure(scene):
    """Same closest hits ⇒ the same image, bit for bit, whatever the structure."""
    algo = registry.get("whitted")
    sc = small(SUITES / scene, 40, 32)
    ref = algo.render(sc, algo.parse_params({"accel": "none", "light_samples": 4})).image
    assert ref.max() > 0
    for name in ("bvh-sah", "grid", "octree", "slabs", "bvh-wide"):
        img = algo.render(sc, algo.parse_params({"accel": name, "light_samples": 4})).image
        np.testing.assert_array_equal(img, ref, err_msg=f"{scene}: accel={name}")


def test_raycast_float32_image_does_not_depend_on_the_structure():
    algo = registry.get("raycast")
    sc = small(SUITES / "cornell" / "cornell_box.xml", 32, 32)
    p = {"precision": "float32", "light_samples": 4}
    ref = algo.render(sc, algo.parse_params({**p, "accel": "none"})).image
    for name in ("bvh-median", "bvh-gs", "bv", "bv-sphere", "bvh-wide"):
        img = algo.render(sc, algo.parse_params({**p, "accel": name})).image
        np.testing.assert_array_equal(img, ref, err_msg=f"accel={name}")


# ---------------------------------------------------------------- packets ---

def test_packets_return_the_single_ray_hits_of_the_same_tree():
    """8×8 eye-ray packets through the BVH: the same depth and primitive buffers as
    single-ray traversal of that BVH, and as brute force."""
    from impl.accel.packets import primary_hits
    from gibench.studies.accel import camera_rays, sphere_field

    scene = sphere_field(400, width=52, height=36)          # tiles cut by the image border
    A = flatten(scene)
    algo = registry.get("whitted")
    for name in ("bvh-sah", "octree", "bvh-wide"):
        R = ray_config(A, algo.parse_params({"accel": name}), algorithm="whitted")
        d1, p1, c1 = primary_hits(R, scene.camera, packets=False)
        d2, p2, c2 = primary_hits(R, scene.camera, packets=True)
        np.testing.assert_array_equal(p2, p1, err_msg=name)
        np.testing.assert_array_equal(d2, d1, err_msg=name)
        assert (p1 >= 0).mean() > 0.3
        assert c2[0] < c1[0], f"{name}: a packet opens each node once for its rays ({c2[0]} vs {c1[0]})"
    R0 = ray_config(A, algo.parse_params({"accel": "none"}), algorithm="whitted")
    o, d = camera_rays(scene)
    _, p0, _, _ = accel.trace_batch(R0, o, d, tmin=0.0)
    np.testing.assert_array_equal(p1.reshape(-1), p0)
    with pytest.raises(ValueError, match="packets need a tree"):
        primary_hits(R0, scene.camera, packets=True)


def test_auto_uses_the_bvh_with_the_stable_form_only():
    """accel=auto (the default): the wide BVH for the stable sphere form from AUTO_MIN_PRIMS
    primitives on; brute force below that, and for the algebraic and geometric forms,
    whose far-field false hits a bounding volume would cull."""
    from impl.rays import AUTO_MIN_PRIMS

    algo = registry.get("whitted")
    small = flatten(load_scene(SUITES / "spheres" / "lit_sphere.xml"))
    assert len(small.sph_radius) + len(small.tri_v) < AUTO_MIN_PRIMS
    assert ray_config(small, algo.parse_params({}), algorithm="whitted").accel == accel.NONE
    A = flatten(load_scene(SUITES / "spheres" / "meshes.xml"))
    assert len(A.sph_radius) + len(A.tri_v) >= AUTO_MIN_PRIMS
    assert algo.parse_params({})["accel"] == "auto"
    kinds = {form: ray_config(A, algo.parse_params({"intersect": form}), algorithm="whitted").accel
             for form in ("stable", "algebraic", "geometric")}
    assert kinds == {"stable": accel.WIDE, "algebraic": accel.NONE, "geometric": accel.NONE}
    R = ray_config(A, algo.parse_params({"intersect": "geometric", "accel": "grid"}), algorithm="whitted")
    assert R.accel == accel.GRID


def test_scaling_fit_recovers_known_exponents_and_logarithmic_work():
    """gibench.studies.accel.fit_exponents on synthetic rows: trace time ∝ N fits exponent 1,
    nodes per ray = 3 + 5·ln N fits slope 5 with R² = 1, and a power law in the node count
    does not fit a line in ln N as well."""
    from gibench.studies.accel import fit_exponents

    rows = []
    for N in (1000, 10000, 100000, 1000000):
        rows.append({"family": "f", "accel": "lin", "N": N, "prims": N, "trace_s": 1e-6 * N,
                     "primary_query_s": 1e-7 * N, "tests_per_ray": float(N),
                     "nodes_per_ray": 3.0 + 5.0 * np.log(N)})
        rows.append({"family": "f", "accel": "pow", "N": N, "prims": N, "trace_s": 1e-3,
                     "primary_query_s": 1e-4, "tests_per_ray": 1.0, "nodes_per_ray": N ** 0.5})
    fits = {f["accel"]: f for f in fit_exponents(rows, n_min=1000)}
    assert fits["lin"]["exponent_trace_time"] == pytest.approx(1.0)
    assert fits["lin"]["nodes_per_ray_per_lnN"] == pytest.approx(5.0)
    assert fits["lin"]["nodes_lnN_r2"] == pytest.approx(1.0)
    assert fits["pow"]["exponent_trace_time"] == pytest.approx(0.0, abs=1e-12)
    assert fits["pow"]["nodes_lnN_r2"] < 0.95


def test_scaling_fit_separates_work_from_cost_per_node():
    """The columns of fit_exponents on synthetic rows: work b·ln(N/N0) has a
    log–log slope above log N's (and N0 is recovered); a query time of exactly 30 ns
    per node gives a per-node slope of 30 and a per-node-time exponent of 0; a cost
    per node growing as N^0.1 gives 0.1."""
    from gibench.studies.accel import fit_exponents

    rows = []
    for N in (1000, 3000, 10000, 30000, 100000):
        nodes = 5.0 * np.log(N / 50.0)
        rows.append({"family": "f", "accel": "flat", "N": N, "prims": N, "trace_s": 1e-3 * nodes,
                     "primary_query_s": 1e-4, "tests_per_ray": 1.5, "nodes_per_ray": nodes,
                     "query_ns_per_ray": 30.0 * nodes, "query_ns_per_node": 30.0})
        rows.append({"family": "f", "accel": "cache", "N": N, "prims": N, "trace_s": 1e-3,
                     "primary_query_s": 1e-4, "tests_per_ray": 1.5, "nodes_per_ray": nodes,
                     "query_ns_per_ray": 30.0 * N ** 0.1 * nodes, "query_ns_per_node": 30.0 * N ** 0.1})
    fits = {f["accel"]: f for f in fit_exponents(rows, n_min=1000)}
    flat = fits["flat"]
    assert flat["nodes_lnN_N0"] == pytest.approx(50.0)
    assert flat["nodes_lnN_r2"] == pytest.approx(1.0)
    assert flat["exponent_nodes_per_ray"] > 1.4 * flat["exponent_log_N"]
    assert flat["exponent_trace_time"] == pytest.approx(flat["exponent_nodes_per_ray"])
    assert flat["trace_lnN_r2"] == pytest.approx(1.0)
    assert flat["query_ns_per_node_fit"] == pytest.approx(30.0)
    assert flat["exponent_ns_per_node"] == pytest.approx(0.0, abs=1e-12)
    assert fits["cache"]["exponent_ns_per_node"] == pytest.approx(0.1)


def test_shuffled_tree_is_the_same_tree_elsewhere_in_memory():
    """gibench.studies.accel.shuffle_node_groups (the layout control of the node_cost
    study): same hits and node counts as the builder's layout, the nodes permuted with
    siblings kept consecutive, and node_cost reports its three cases."""
    from gibench.studies.accel import camera_rays, node_cost, shuffle_node_groups, sphere_field

    scene = sphere_field(300, width=32, height=24)
    R = ray_config(flatten(scene), registry.get("whitted").parse_params({"accel": "bvh-sah"}),
                   algorithm="whitted")
    S = shuffle_node_groups(R, np.random.default_rng(3))
    assert not np.array_equal(S.node_a, R.node_a)
    np.testing.assert_array_equal(np.sort(S.node_b), np.sort(R.node_b))
    np.testing.assert_array_equal(S.node_lo[0], R.node_lo[0])
    o, d = camera_rays(scene)
    t1, p1, _, c1 = accel.trace_batch(R, o, d)
    t2, p2, _, c2 = accel.trace_batch(S, o, d)
    np.testing.assert_array_equal(p2, p1)
    np.testing.assert_array_equal(t2, t1)
    np.testing.assert_array_equal(c2, c1)
    rows = node_cost(sizes=(300,), width=32, height=24, tile=8, repeats=1, log=lambda *_: None)
    assert [r["case"] for r in rows] == ["full", "tile", "shuffled"]
    assert rows[0]["nodes_per_ray"] == rows[2]["nodes_per_ray"] == pytest.approx(c1[:, 0].mean())
    assert all(r["ns_per_node"] > 0 and r["rays"] == 32 * 24 for r in rows)
    with pytest.raises(ValueError, match="structure must be a tree"):
        node_cost(sizes=(10,), structure="grid")


# ------------------------------------------------------- grid knobs (2.6.2) ---

@pytest.mark.parametrize("density", [0.3, 1.0, 4.0, 20.0])
def test_grid_knobs_keep_brute_force_hits_and_mailboxing_saves_tests(density):
    """Every grid resolution, mailbox on or off, answers closest and any-hit queries as
    brute force; turning the mailbox off only adds tests (a primitive listed in several
    pierced voxels is tested in each)."""
    rng = np.random.default_rng(SEED + 31)
    c, r, v, shape = random_scene(rng, 150, 150)
    o, d = random_rays(rng, 3000)
    _, p0, _, _ = accel.trace_batch(config(c, r, v, shape, "none", np.float64), o, d)
    tests = {}
    for mailbox in (True, False):
        R = config(c, r, v, shape, "grid", np.float64, grid_density=density, grid_mailbox=mailbox)
        _, p, _, counts = accel.trace_batch(R, o, d)
        np.testing.assert_array_equal(p, p0, err_msg=f"density {density} mailbox={mailbox}")
        tests[mailbox] = counts[:, 1]
        tmax = np.full(len(o), 1.5)
        want, _ = accel.occluded_batch(config(c, r, v, shape, "none", np.float64), o, d, 0.0, tmax)
        got, _ = accel.occluded_batch(R, o, d, 0.0, tmax)
        np.testing.assert_array_equal(got, want, err_msg=f"any-hit, density {density} mailbox={mailbox}")
    assert (tests[False] >= tests[True]).all() and tests[False].sum() > tests[True].sum()


def fig_2_34():
    """Thesis Fig. 2.34 as primitives: a slanted triangle B whose box spans the whole
    grid, hit by the ray along +x (y = z = 0, from x = −2) at x = 0.7, in the last
    voxel; a small sphere C at x = 0.3 (hit at x = 0.2), listed in the middle voxels
    only.  Returns (centres, radii, triangles, ray origin, ray direction)."""
    c = np.array([[0.3, 0.0, 0.0]])
    r = np.array([0.1])
    v = np.array([[[-0.9, -1.0, -1.0], [-0.9, 1.0, -1.0], [0.9, 0.0, 0.125]]])
    return c, r, v, np.array([[-2.0, 0.0, 0.0]]), np.array([[1.0, 0.0, 0.0]])


def test_without_the_current_voxel_rule_the_grid_loses_the_nearer_object():
    """Fig. 2.34: B is found in the first voxel the ray enters but lies beyond it; C, nearer,
    waits in the next voxel.  With the rule the grid returns C (brute force's answer);
    without it the search ends at B.  Mailboxing saves B's second test."""
    c, r, v, o, d = fig_2_34()
    shape = np.arange(2)
    brute = accel.trace_batch(config(c, r, v, shape, "none", np.float64), o, d)
    assert brute[1][0] == 0 and abs(brute[0][0] - 2.2) < 1e-9            # the sphere, at x = 0.2
    R = config(c, r, v, shape, "grid", np.float64, grid_density=16.0)
    assert R.acc_i[0] == 3                                               # voxels x: [-.9,-.3], [-.3,.3], [.3,.9]
    t, p, _, counts = accel.trace_batch(R, o, d)
    assert p[0] == 0 and t[0] == brute[0][0] and counts[0, 1] == 2
    t, p, _, counts_nomb = accel.trace_batch(
        config(c, r, v, shape, "grid", np.float64, grid_density=16.0, grid_mailbox=False), o, d)
    assert p[0] == 0 and counts_nomb[0, 1] == 3                          # B tested again in voxel 2
    t, p, _, _ = accel.trace_batch(
        config(c, r, v, shape, "grid", np.float64, grid_density=16.0, grid_current_voxel=False), o, d)
    assert p[0] == 1 and abs(t[0] - 2.7) < 1e-9                          # the triangle, at x = 0.7


def _shrunk_boxes(R, f):
    """R with every tree node box shrunk about its centre to the fraction ``f``."""
    mid = 0.5 * (R.node_lo + R.node_hi)
    half = 0.5 * (R.node_hi - R.node_lo) * f
    return R._replace(node_lo=mid - half, node_hi=mid + half)


def test_the_brute_force_check_fails_for_broken_structures():
    """Negative controls of the brute-force check (thesis 1.2.4, 2.6): the check of
    ``test_every_structure_returns_the_brute_force_closest_hit`` (same primitive on every
    ray) rejects a grid without the current-voxel rule and a BVH whose node boxes are 10 %
    too small, on the same random scenes; and the exact variants pass it."""
    rng = np.random.default_rng(SEED)
    c, r, v, shape = random_scene(rng, 150, 150)
    o, d = random_rays(rng, 4000)
    _, p0, _, _ = accel.trace_batch(config(c, r, v, shape, "none", np.float64), o, d)

    def mismatches(R):
        return int((accel.trace_batch(R, o, d)[1] != p0).sum())

    grid = config(c, r, v, shape, "grid", np.float64)
    bvh = config(c, r, v, shape, "bvh-sah", np.float64)
    assert mismatches(grid) == 0 and mismatches(bvh) == 0
    assert mismatches(config(c, r, v, shape, "grid", np.float64, grid_current_voxel=False)) > 0
    assert mismatches(_shrunk_boxes(bvh, 0.9)) > 0


def test_grid_knobs_are_ray_parameters():
    """The three knobs reach the grid through the ray tracers' parameters, a bad density
    is refused with one line naming it, and the rule changes a Whitted image."""
    from gibench.studies.accel import sphere_field

    algo = registry.get("whitted")
    scene = sphere_field(1000, width=64, height=48)
    A = flatten(scene)
    R = ray_config(A, algo.parse_params({"accel": "grid", "grid_density": 0.5, "grid_mailbox": False,
                                         "grid_current_voxel": False}), algorithm="whitted")
    assert list(R.acc_i[3:]) == [0, 0] and np.prod(R.acc_i[:3]) <= 0.5 * len(A.sph_radius) + 64
    with pytest.raises(ValueError, match="grid_density must be finite and > 0, got 0.0"):
        ray_config(A, algo.parse_params({"accel": "grid", "grid_density": 0.0}), algorithm="whitted")
    exact = algo.render(scene, algo.parse_params({"accel": "grid"})).image
    brute = algo.render(scene, algo.parse_params({"accel": "none"})).image
    broken = algo.render(scene, algo.parse_params({"accel": "grid", "grid_current_voxel": False})).image
    np.testing.assert_array_equal(exact, brute)
    assert np.any(broken != exact, axis=-1).sum() > 0


def test_grid_knobs_study_shows_wrong_hits_only_without_the_current_voxel_rule():
    """The grid_knobs study on a 1000-sphere field: zero wrong hits and pixels with the
    rule (mailbox on or off), some without it; mailboxing lowers the tests per ray; the
    render phases come from RenderResult.timings."""
    from gibench.studies.accel import grid_knobs

    rows = grid_knobs(families=("spheres",), sizes={"spheres": 1000}, densities=(1.0, 8.0),
                      width=64, height=48, repeats=1, log=lambda *_: None)
    assert len(rows) == 8
    for row in rows:
        wrong = row["wrong_hits"] + row["bounce_wrong_hits"]
        if row["current_voxel"]:
            assert wrong == 0 and row["wrong_pixels"] == 0, row
        else:
            assert wrong > 0, row
        assert row["trace_s"] > 0 and row["setup_s"] > 0
    by = {(r["density"], r["mailbox"], r["current_voxel"]): r for r in rows}
    for dens in (1.0, 8.0):
        assert by[dens, False, True]["tests_per_ray"] > by[dens, True, True]["tests_per_ray"]
    assert sum(r["wrong_pixels"] for r in rows if not r["current_voxel"]) > 0


def test_scaling_study_reports_the_render_phases():
    from gibench.studies.accel import scaling

    rows = scaling(families=("spheres",), sizes={"spheres": [10, 100]}, structures=["none", "grid"],
                   width=16, height=12, repeats=1, log=lambda *_: None)
    assert len(rows) == 4
    for row in rows:
        assert 0 < row["trace_s"] < row["render_s"] and row["setup_s"] > 0 and row["build_s"] > 0
