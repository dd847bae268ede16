"""The batch kernels run without numba's runtime (no reference counting), and the
functions that allocate and can be reached from them keep it.

A kernel that lost ``batch_kernel`` would still compute the same image, only slower
(atomic reference counts inside the per-ray loops), and so would a per-ray helper that
lost its inlining (its arguments copied at every call), so both options are pinned here;
a function that allocates must state ``_nrt=True`` or a batch kernel calling it first
would compile it without the runtime and fail.
"""

import numpy as np
import pytest
from numba import njit
from numba.core.errors import TypingError

from impl import (accel, bsdf, light_sampling, lighting, path, path_lanes, projector, raycast, rays,
                  shading_frame, spectral, textures, tracer, whitted)
from impl.accel import wide
from impl.kernel import batch_kernel, run_tasks, take_task

BATCH_KERNELS = [tracer.eye_batch, raycast._shade, lighting.direct_batch, lighting._delta_lanes,
                 lighting._copy_lane, lighting._add_lit, lighting._lit_lanes, raycast._plain_hits,
                 whitted._trees,
                 whitted._shade, path._start, path._sobol_numbers, path._light_samples, path._vertices,
                 path._unblocked, path._to_srgb, path_lanes._lanes, wide.wide_closest, wide.wide_any,
                 wide.wide_closest_bound, wide.wide_any_bound, wide.wide_frustum_prims,
                 wide.wide_closest_rays, wide.wide_occluded_rays, tracer.closest_batch, tracer._closest_chunks,
                 tracer.occluded_batch, tracer._occluded_chunks, tracer._chunk_cull, tracer._tile_candidates,
                 spectral.to_linear_srgb]
#: Called per ray from batch kernels: inlined (a call would pass every array of the scene,
#: material or ray-configuration tuple it takes, member by member).
#: Lane kernels given rows that never overlap: declared ``noalias`` (``disjoint=True``).
DISJOINT = [path_lanes._lanes, path._sobol_numbers, lighting._area_lanes, lighting._delta_lanes,
            lighting._copy_lane, lighting._add_lit, tracer._closest_loops, tracer._closest_loops_from,
            tracer._occluded_loops, raycast._plain_hits]
PER_RAY = [bsdf.bsdf_sample, bsdf.bsdf_eval, bsdf.bsdf_pdf, light_sampling.sample_light,
           light_sampling.emitter_pdf, rays.hit, rays.occluded, wide.wide_bind,
           shading_frame.perturbed_normal, shading_frame.same_side, shading_frame.shadow_terminator,
           textures.bitmap_grad, projector.projector_weight]
ALLOCATING = [accel.closest,
              accel.any_hit, accel.closest_rays, accel.occluded_rays, bsdf._plastic_sample, bsdf._plastic_eval,
              bsdf._plastic_pdf]


@pytest.mark.parametrize("fn", BATCH_KERNELS, ids=lambda f: f.py_func.__qualname__)
def test_batch_kernels_are_compiled_without_the_runtime(fn):
    assert fn.targetoptions.get("_nrt") is False
    assert fn._cache is not None and type(fn._cache).__name__ == "FunctionCache"   # cache=True


@pytest.mark.parametrize("fn", PER_RAY, ids=lambda f: f.py_func.__qualname__)
def test_per_ray_helpers_are_inlined_into_the_batch_kernels(fn):
    assert fn.targetoptions.get("inline") == "always"


@pytest.mark.parametrize("fn", ALLOCATING, ids=lambda f: f.py_func.__qualname__)
def test_allocating_callees_state_the_runtime(fn):
    assert fn.targetoptions.get("_nrt") is True


@pytest.mark.parametrize("fn", DISJOINT, ids=lambda f: f.py_func.__qualname__)
def test_lane_kernels_declare_their_arrays_disjoint(fn):
    assert fn.targetoptions.get("_noalias") is True


def _axpy_rows(a, x0, x1, x2, x3, y0, y1, y2, y3):
    for i in range(x0.shape[0]):
        y0[i] = a * x0[i] + y0[i]
        y1[i] = a * x1[i] + y1[i]
        y2[i] = a * x2[i] + y2[i]
        y3[i] = a * x3[i] + y3[i]


def test_disjoint_kernels_vectorise_without_overlap_checks():
    """``disjoint=True`` marks the arrays ``noalias``: the same results, and LLVM drops the
    run-time overlap checks it otherwise puts before the vector loop (each a pair of
    address comparisons, 4 written rows against 8 arrays here)."""
    rows = np.random.default_rng(2).random((8, 257))
    out = {}
    for disjoint in (False, True):
        k = batch_kernel(cache=False, disjoint=disjoint)(_axpy_rows)
        r = rows.copy()
        k(1.5, *r[:4], *r[4:])
        out[disjoint] = (r, k.inspect_asm(k.signatures[0]))
    np.testing.assert_array_equal(out[False][0], out[True][0])
    np.testing.assert_allclose(out[True][0][4:], 1.5 * rows[:4] + rows[4:], rtol=0, atol=0)

    def compares(asm):
        return sum(line.split()[0] in ("cmpq", "setb", "setae") for line in asm.splitlines() if line.strip())

    assert "ymm" in out[True][1] or "zmm" in out[True][1]
    assert compares(out[True][1]) + 8 < compares(out[False][1])


def test_a_batch_kernel_cannot_allocate():
    @batch_kernel(cache=False)
    def bad(n):
        a = np.empty(n)
        return a.sum()

    with pytest.raises(TypingError):
        bad(3)


def test_a_batch_kernel_computes_what_the_runtime_version_does():
    def body(x, out):
        for i in range(x.shape[0]):
            out[i] = x[i] * x[i] if x[i] > 0.5 else -x[i]

    x = np.random.default_rng(1).random(1000)
    a, b = np.empty_like(x), np.empty_like(x)
    batch_kernel(cache=False)(body)(x, a)
    njit(body)(x, b)
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("n", [1, 2, 3, 7, 12, 64, 300, 19200, 65536])
def test_strided_task_order_visits_every_task_once_and_spreads_each_half(n):
    """The parallel loops' task order (``impl.kernel.task_stride``): a bijection of
    0..n−1, and each contiguous half of the iterations (what numba's static schedule
    gives one of two threads) takes tasks from both halves of the image about evenly —
    the image order (stride 1) gives one thread all of the top half."""
    from impl.kernel import interleaved, task_stride

    s = task_stride(n)
    order = np.array([interleaved(c, n, s) for c in range(n)])
    assert sorted(order) == list(range(n))
    if n >= 64:
        first = order[: n // 2]
        assert abs((first < n // 2).mean() - 0.5) < 0.05
        naive = np.array([interleaved(c, n, 1) for c in range(n // 2)])   # image order
        assert (naive < n // 2).mean() == 1.0


@njit(nogil=True, cache=True)
def _count_tasks(n, taken, spin, queue):
    """Task loop: task c adds one to ``taken[c]`` after ``spin`` dependent steps."""
    c = take_task(queue)
    while c < n:
        x = 0.0
        for k in range(spin):
            x = x * 0.5 + k
        taken[c] += 1 if x >= 0.0 else 2
        c = take_task(queue)


@njit(nogil=True, cache=True)
def _fail_at(n, bad, done, queue):
    c = take_task(queue)
    while c < n:
        if c == bad:
            raise ValueError("task failed")
        done[c] = 1
        c = take_task(queue)


@pytest.mark.parametrize("n, spin", [(0, 0), (1, 0), (5, 0), (200_000, 0), (2_000, 2_000)])
def test_task_queue_runs_every_task_exactly_once(n, spin):
    """``impl.kernel.run_tasks``: every thread takes numbers from one queue with an atomic
    fetch-and-add, so each task runs once — a plain read-then-increment would let two
    threads take the same number, which many tiny tasks (200 000 of them) would show."""
    import numba

    if numba.get_num_threads() < 2:
        pytest.skip("one numba thread: no other thread to race")
    for _ in range(3):                   # the first run may start the helper threads late
        taken = np.zeros(n, np.int64)
        run_tasks(_count_tasks, n, taken, spin)
        assert (taken == 1).all()


def test_task_queue_raises_a_kernel_error_after_every_thread_stopped():
    """The thread that fails stops; the others run the remaining tasks to the end before
    the error is raised, so nothing writes into the arrays after ``run_tasks`` returns."""
    import numba

    done = np.zeros(1000, np.int64)
    with pytest.raises(ValueError, match="task failed"):
        run_tasks(_fail_at, 1000, 500, done)
    assert done[500] == 0
    if numba.get_num_threads() >= 2:
        assert done.sum() == 999


def _placeable():
    import os

    from impl import kernel

    return kernel._getcpu is not None and len(os.sched_getaffinity(0)) >= 2


@pytest.mark.skipif(not _placeable(), reason="needs sched_getcpu and two processors to pin to")
def test_helpers_run_on_processors_other_than_the_callers():
    """Before the helpers are woken each is pinned to one processor of the caller's mask
    that the caller is not on (a helper woken onto the caller's busy processor waits for
    a time slice there)."""
    import os

    from impl import kernel

    helpers = kernel._threads(1)
    allowed = os.sched_getaffinity(0)
    apart = 0
    for _ in range(5):                   # the caller may move between the two reads
        kernel._place(helpers)
        mask = os.sched_getaffinity(helpers[0].tid)
        assert len(mask) == 1 and mask <= allowed
        apart += mask != {kernel._getcpu()}
    assert apart >= 4


@pytest.mark.skipif(not _placeable(), reason="needs sched_getcpu and two processors to pin to")
def test_helpers_are_left_unpinned_when_the_caller_has_one_processor():
    """A caller confined to one processor leaves its helpers that processor's mask (no
    other to pin them to), and the tasks still run once each."""
    import os

    import numba

    from impl import kernel

    before = os.sched_getaffinity(0)
    one = {min(before)}
    helpers = kernel._threads(max(1, numba.get_num_threads() - 1))
    try:
        os.sched_setaffinity(0, one)
        kernel._place(helpers)
        assert all(os.sched_getaffinity(h.tid) == one for h in helpers)
        taken = np.zeros(5000, np.int64)
        run_tasks(_count_tasks, 5000, taken, 10)
        assert (taken == 1).all()
    finally:
        os.sched_setaffinity(0, before)


def test_task_queue_refuses_a_kernel_that_holds_the_gil():
    @njit
    def holds(queue):
        return None

    with pytest.raises(TypeError, match="nogil"):
        run_tasks(holds)


def test_the_tracers_render_loops_are_task_loops():
    """The tile tracers' render loops release the GIL (so :func:`impl.kernel.run_tasks`
    runs them on every thread) and are not numba ``prange`` loops (whose outlined body
    numba optimises again with the whole tracer linked in)."""
    for fn in (raycast._render_kernel, whitted._render_kernel, path._render_kernel):
        assert fn.targetoptions.get("nogil") and not fn.targetoptions.get("parallel")


@pytest.mark.parametrize("tx, ty", [(1, 1), (7, 5), (8, 6), (1, 9), (40, 30)])
def test_tiles_are_handed_out_centre_first(tx, ty):
    """``impl.tracer.centre_out``: every tile once, by non-decreasing distance of its
    centre from the image centre (the last ones at the corners)."""
    order = tracer.centre_out(tx, ty)
    assert order.dtype == np.int64 and sorted(order) == list(range(tx * ty))
    x, y = order % tx, order // tx
    d2 = (2 * x - (tx - 1)) ** 2 + (2 * y - (ty - 1)) ** 2
    assert (np.diff(d2) >= 0).all()
    corners = {0, tx - 1, (ty - 1) * tx, tx * ty - 1}
    assert order[-1] in corners


def test_the_collector_is_relaxed_during_a_compile_and_restored_after():
    """A numba compile runs with :data:`impl.kernel.COMPILE_GC_THRESHOLDS` (seen from a
    callee's compile, nested in its caller's) and leaves the thresholds it found, also
    when the compile fails."""
    import gc

    from numba.core import event

    from impl.kernel import COMPILE_GC_THRESHOLDS

    seen = []

    class Probe(event.Listener):
        def on_start(self, ev):
            seen.append((ev.data["dispatcher"].py_func.__name__, gc.get_threshold()))

        def on_end(self, ev):
            pass

    @njit
    def callee(x):
        return x + 1

    @njit
    def caller(x):
        return callee(x) * 2

    @njit
    def broken(x):
        return x.no_such_attribute

    before = gc.get_threshold()
    gc.set_threshold(500, 7, 9)
    probe = Probe()
    event.register("numba:compile", probe)
    try:
        assert caller(3) == 8
        assert gc.get_threshold() == (500, 7, 9)
        with pytest.raises(TypingError):
            broken(1)
        assert gc.get_threshold() == (500, 7, 9)
    finally:
        event.unregister("numba:compile", probe)
        gc.set_threshold(*before)
    assert ("callee", COMPILE_GC_THRESHOLDS) in seen and ("caller", COMPILE_GC_THRESHOLDS) in seen
    assert ("broken", COMPILE_GC_THRESHOLDS) in seen


@njit(inline="always")
def _inlined_leaf(x):
    s = 0.0
    for i in range(3):
        if x > i:
            s += x * i
        else:
            s -= i
    return s


@njit(inline="always")
def _inlined_middle(x):
    return _inlined_leaf(x) + _inlined_leaf(x + 1.0)


@njit
def _inlined_top(x):
    return _inlined_middle(x) * 2.0 + _inlined_leaf(-x)


def test_an_inlined_callees_block_copies_share_one_scope():
    """Inside one inlining (``InlineWorker.inline_ir``) the copies of a function's blocks
    share one copy of its scope, as the original blocks share the original: each block's
    copy no longer copies the whole variable table.  Outside an inlining a block's copy
    is numba's own (a scope of its own)."""
    from numba.core import inline_closurecall
    from numba.core.compiler import run_frontend

    from impl.kernel import INLINED_COPIES_SHARED

    assert INLINED_COPIES_SHARED, "numba's inliner changed shape: its block copies are quadratic again"

    ir = run_frontend(_inlined_leaf.py_func)
    assert len(ir.blocks) > 3
    shim = inline_closurecall.copy
    shared = shim.sharing(lambda worker: [shim.deepcopy(b) for b in ir.blocks.values()])(None)
    scopes = {id(b.scope) for b in shared}
    assert len(scopes) == 1 and id(next(iter(ir.blocks.values())).scope) not in scopes
    assert [str(b) for b in shared] == [str(b) for b in ir.blocks.values()]
    alone = [shim.deepcopy(b) for b in ir.blocks.values()]
    assert len({id(b.scope) for b in alone}) == len(alone)


@pytest.mark.parametrize("x", [-2.0, 0.5, 1.5, 7.0])
def test_nested_inlined_callees_compute_what_python_does(x):
    """Callees inlined at several sites and inside each other (the shared block copies
    of every inlining) compute what the Python functions compute."""
    assert _inlined_top(x) == _inlined_top.py_func(x)


def _compiled_signatures(dispatcher):
    """The signatures ``dispatcher`` holds compiled in this process or in numba's cache
    (a function compiled into its callers' cached code need not be loaded itself; the
    cache index is read through numba's private ``_cache._cache_file``)."""
    cached = [key[0] for key in dispatcher._cache._cache_file._load_index()]
    return list(dispatcher.signatures) + cached


def test_the_large_shading_kernels_are_not_compiled_for_literal_arguments():
    """numba compiles a function once more for every literal value a caller passes (a
    ``False``, a ``0``, a loop counter that starts at 0): the scalar light estimator and
    distributed's ray-tree kernel are large, so their callers pass typed values.  After
    renders that reach every call site (distributed's pixel loop holds all its per-sample
    samplers' branches, its packet tiles call the tree kernel too, its tile batches call their
    shading step for eye rays and for deeper chunks; the z-buffer's Gouraud shading
    calls the estimator with shadows off), none of their compiled signatures, here or in
    the cache, holds a literal, and every call site of the tree kernel and of the batch
    shading step has one and the same signature (the arrays it is given sliced alike)."""
    import dataclasses
    from pathlib import Path

    from numba.core import types

    from core.loader import load_scene
    from impl import distributed, zbuffer

    suites = Path(__file__).resolve().parent.parent / "suites"
    # Poisson patterns go through the per-sample trees (pixel loop, packet tiles), the
    # other fixed-count samplers through the tile batches (with and without packets).
    gloss, D = "distributed/gloss.xml", distributed.ALGORITHM
    for rel, algo, params in ((gloss, D, {"spp": 4, "sampler": "poisson"}),
                              (gloss, D, {"spp": 4, "sampler": "poisson", "packets": True}),
                              (gloss, D, {"spp": 4, "packets": True}),
                              ("cornell/cornell_box.xml", D, {"spp": 4, "dimensions": "stratified"}),
                              ("cornell/cornell_box.xml", zbuffer.ALGORITHM, {"shading": "gouraud"})):
        scene = load_scene(suites / rel)
        film = dataclasses.replace(scene.camera.film, width=4, height=3)
        scene.camera = dataclasses.replace(scene.camera, film=film)
        algo.render(scene, algo.parse_params(params), seed=0)
    for fn in (lighting._direct_light_rays, distributed._trees, distributed._shade_batch):
        sigs = _compiled_signatures(fn)
        assert sigs, fn.py_func.__qualname__
        assert [s for s in sigs if any(isinstance(a, types.Literal) for a in s)] == [], \
            fn.py_func.__qualname__
    assert len(set(_compiled_signatures(distributed._trees))) == 1
    assert len(set(_compiled_signatures(distributed._shade_batch))) == 1
