"""How the tracers' hot batch kernels are compiled.

numba manages array lifetimes with atomic reference counts (its runtime, NRT):
every array value a function creates — a member read from a tuple of arrays, an
argument bound by an inlined helper, a view — is incremented and later
decremented.  Its refcount pruning removes the pairs it can prove redundant,
but not across the branches and calls of a shading loop, so the counts stay
*inside* the per-ray loops, on arrays shared by both threads: atomic updates of
one cache line from two cores.  On the ray tracers' shading and lighting loops
they cost several times the arithmetic (a profile of a ray-cast render showed
most of the kernel's time on two atomic instructions).

A batch kernel takes every array it needs from its caller and allocates none,
so it needs no runtime: :func:`batch_kernel` compiles it with numba's runtime
off (the ``_nrt`` option of :func:`numba.njit`), which emits no reference
counting at all.  The caller (a tile function, which allocates the batch's
arrays) keeps the arrays alive for the call.  A function compiled this way
cannot create an array (``np.empty``, a copy, an array-valued expression):
numba refuses to compile it, naming the operation.  Helpers it calls with
``inline="always"`` are compiled into it.  A separate njit function it calls
*inherits* the setting unless it states its own, and numba keeps one compiled
version per signature, whichever caller came first: so every njit function that
allocates and can be reached from a batch kernel states ``_nrt=True`` (the
acceleration structures' query entry points, :func:`impl.tracer.closest_batch`
and ``occluded_batch``, the plastic BSDF lobes of :mod:`impl.bsdf`).

What a batch kernel calls once per ray (a path vertex's light sample and BSDF, the
wide BVH's traversal behind :func:`impl.rays.hit` and ``occluded``) is inlined into
it (``inline="always"``): a call of a separate njit function passes a tuple of
arrays (the flattened scene, the materials, the ray configuration) member by
member, every array's data pointer, shape and strides, which costs more than the
work of a light sample.  The wide BVH's stand-alone queries
(:func:`impl.accel.wide.wide_closest`, ``wide_any``) are batch kernels, whichever
caller compiles them first.
"""

from __future__ import annotations

from numba import njit

__all__ = ["batch_kernel"]


def batch_kernel(fn=None, **options):
    """``@batch_kernel`` or ``@batch_kernel(error_model="numpy", ...)``: ``numba.njit``
    with ``cache=True`` and without the runtime (no reference counting, no
    allocation; see the module docstring)."""
    opts = {"cache": True, "_nrt": False, **options}
    if fn is None:
        return njit(**opts)
    return njit(**opts)(fn)
