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

What a batch kernel calls once per ray is either inlined into it
(``inline="always"``: a path vertex's light sample and BSDF) or takes no tuple of
arrays: a call of a separate njit function passes a tuple of arrays (the flattened
scene, the materials, the ray configuration) member by member, every array's data
pointer, shape and strides, which costs more than the work of a light sample.  The
wide BVH's traversal behind :func:`impl.rays.hit` and ``occluded`` is such a call
(:func:`impl.accel.wide.wide_closest_bound`, ``wide_any_bound``): it takes the
tree's data pointers, bound inline from the configuration, and is compiled once,
with its own error model (inlined, it would take the caller's, where ``1 / 0.0``
of an axis-parallel ray raises instead of giving ∞), rather than once per call
site.  These and the stand-alone queries (``wide_closest``, ``wide_any``) are
batch kernels, whichever caller compiles them first.

numba types a ``prange`` loop twice: as a plain loop, where its index is int64, and
again in the parallel body it outlines, where the index is uint64.  A separate njit
function that takes the index (or a value computed from it) is therefore compiled
for both signatures, its whole call tree twice.  The loops where this was seen (the
z-buffer's shading, form factors, radiosity, the acceleration structures' query
kernels, the film filter) take ``np.int64(index)`` first, so both typings pass one
type.  The tile loops of raycast, whitted and path are task loops, not ``prange``
(see :func:`run_tasks`); distributed's loops and raycast's depth pass are not
checked.  A literal
argument (``False``, ``0``, ``-1``) is such a second type too, beside the variables
other call sites pass: those calls pass a typed value.
"""

from __future__ import annotations

import concurrent.futures
import ctypes
import gc
import math
import os
import queue
import threading

import llvmlite.binding as _llvm
import numba
import numba.core.event
from numba.core import cpu as _cpu
from numba.core import options as _options
import numpy as np
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

__all__ = ["batch_kernel", "by_reference", "dereference", "interleaved", "run_tasks", "take_task",
           "task_stride"]

#: LLVM's loop vectoriser versions a loop over arrays it cannot prove disjoint with
#: run-time overlap checks, and gives the loop up (scalar code) when it would need more
#: checks than a small threshold: a batch step that reads a dozen rows of ray and point
#: data and writes a dozen others (a light sample and its shadow ray per point) stayed
#: scalar.  The checks run once per loop, not per ray, so the limits are raised for every
#: kernel compiled in this process (``njit`` takes no keyword declaring its array
#: arguments ``noalias``; see the mapping below for the kernels that can promise it).  LLVM reads these options when it vectorises: kernels loaded from numba's
#: cache were compiled with them already.
LLVM_OPTIONS = ("-runtime-memory-check-threshold=4096", "-vectorize-memory-check-threshold=4096",
                "-memory-check-merge-threshold=4096")
for _option in LLVM_OPTIONS:
    _llvm.set_option("gibench", _option)

#: Kernels whose arrays never overlap say so instead (``batch_kernel(disjoint=True)``):
#: numba's compiler flags carry a ``noalias`` option, which marks every pointer argument
#: of the function LLVM ``noalias``, but its ``njit`` takes no such keyword; this mapping
#: adds one (``_noalias``, as ``_nrt`` maps the flag ``nrt``).  Its loops then vectorise
#: with no overlap checks at all: with a lane kernel's fifty arrays those checks were
#: thousands of instructions at every call.
if not hasattr(_cpu.CPUTargetOptions, "_noalias"):
    _cpu.CPUTargetOptions._noalias = _options._mapping("noalias")


# ------------------------------------------------------------ by reference ---
#
# numba passes a tuple to a function it calls (one not inlined) field by field: every
# array of the flattened scene as its pointer, sizes and strides, several hundred
# scalars, most of them on the stack, at every call.  For a function called per sample
# (distributed's ray tree) that copying cost more than the tree itself.  by_reference
# copies the tuple once onto the caller's stack and passes its address; the callee
# reads it with dereference, and LLVM loads only the fields the callee uses.  The
# pointer is valid for the caller's frame: pass it down, never return or store it.


@intrinsic
def by_reference(typingctx, value):
    """A pointer (``types.CPointer``) to a copy of ``value`` in the calling function's
    stack frame (allocated once, at its entry), for a callee to read with
    :func:`dereference`; a pointer given to it is returned as it is, so a helper can take
    either.  The copy borrows the arrays' references."""
    if isinstance(value, types.CPointer):
        return value(value), lambda context, builder, sig, args: args[0]

    def codegen(context, builder, sig, args):
        ptr = cgutils.alloca_once(builder, context.get_data_type(value))
        context.pack_value(builder, value, args[0], ptr)
        return ptr
    return types.CPointer(value)(value), codegen


@intrinsic
def dereference(typingctx, ptr):
    """The value :func:`by_reference` copied to the address ``ptr`` (a new reference
    where numba counts references)."""
    if not isinstance(ptr, types.CPointer):
        return None

    def codegen(context, builder, sig, args):
        value = context.unpack_value(builder, ptr.dtype, args[0])
        if context.enable_nrt:
            context.nrt.incref(builder, ptr.dtype, value)
        return value
    return ptr.dtype(ptr), codegen


# ---------------------------------------------------- compile-time collection ---
#
# A cold compile of a tracer's kernel is mostly numba's Python front end (typing,
# inlining, lowering), which builds millions of short-lived IR objects, many in reference
# cycles.  With CPython's default thresholds (700, 10, 10) the cyclic collector runs every
# 700 allocations and fully every hundred of those, each full run walking the whole heap,
# which keeps growing during the compile: in a profile of a cold compile the collector is
# a large share of the process (the README has the figures).  For the length of a compile
# the thresholds are raised (:data:`COMPILE_GC_THRESHOLDS`: young collections about 140
# times rarer, full ones in proportion; the collector stays enabled, so the cyclic
# garbage is still freed) and restored afterwards.  Disabling the collector instead would
# keep all of the compile's cyclic garbage until its end, several times the memory.  The
# thresholds are the process's, so while a compile runs (numba compiles under one global
# lock) other threads collect with them too.

#: The collector's thresholds (``gc.set_threshold``) while numba compiles.
COMPILE_GC_THRESHOLDS = (100_000, 10, 10)


class _CompileCollection(numba.core.event.Listener):
    """Raises the collector's thresholds at the start of the outermost numba compile (an
    event ``numba:compile``: a kernel not found in the cache) and restores the ones it
    found when that compile ends; nested compiles (callees) change nothing.  numba emits
    these events under its global compiler lock, so the depth is one thread's."""

    def __init__(self):
        self.depth = 0
        self.saved = None

    def on_start(self, event):
        self.depth += 1
        if self.depth == 1:
            self.saved = gc.get_threshold()
            gc.set_threshold(*COMPILE_GC_THRESHOLDS)

    def on_end(self, event):
        self.depth -= 1
        if self.depth == 0 and self.saved is not None:
            gc.set_threshold(*self.saved)
            self.saved = None


numba.core.event.register("numba:compile", _CompileCollection())


# ------------------------------------------------------------ inlined copies ---
#
# numba inlines a callee (``inline="always"``) by copying its IR, block by block, with a
# ``copy.deepcopy`` of each block (``InlineWorker.inline_ir``, twice per call site: the
# copy it splices in and an unmodified one it returns).  Every variable of a block refers
# to the function's one scope, which lists every variable of the function, and each
# block's copy has a memo of its own: so each block copies the whole variable table
# again, blocks × variables per copy (numba issue 8989, open).  A callee that inlines
# others has thousands of both, and these copies are then a large part of a tracer's
# cold compile (the README has the figures).  For the length of each ``inline_ir`` call,
# the blocks' copies share one memo (:class:`_InlinerCopy`): the scope and each variable
# are copied once, and the copied blocks share them as the original blocks do.  The IR
# that results is numba's own, without the duplicated scopes.  Installed only where
# numba's inliner has the shape this relies on (a module-level ``copy`` and
# ``InlineWorker.inline_ir``); elsewhere numba's own copying stays.


class _InlinerCopy:
    """Stands for the ``copy`` module in ``numba.core.inline_closurecall``: a ``deepcopy``
    of an IR block (without a memo of its caller's) inside an ``inline_ir`` call uses that
    call's memo; every other name is the ``copy`` module's."""

    def __init__(self, module):
        self._module = module
        self._memos = threading.local()

    def __getattr__(self, name):
        return getattr(self._module, name)

    def deepcopy(self, x, memo=None):
        stack = getattr(self._memos, "stack", None)
        if memo is None and stack and isinstance(x, numba.core.ir.Block):
            memo = stack[-1]
        return self._module.deepcopy(x, memo)

    def sharing(self, inline_ir):
        """``inline_ir`` wrapped: one memo for the block copies of each call."""
        def wrapped(worker, *args, **kwargs):
            stack = self._memos.__dict__.setdefault("stack", [])
            stack.append({})
            try:
                return inline_ir(worker, *args, **kwargs)
            finally:
                stack.pop()
        wrapped.__wrapped__ = inline_ir
        wrapped.__doc__ = inline_ir.__doc__
        return wrapped


def _share_inlined_copies() -> bool:
    """Install :class:`_InlinerCopy` in numba's inliner (once); whether it is in place."""
    import copy as copy_module

    from numba.core import inline_closurecall as icc
    worker = getattr(icc, "InlineWorker", None)
    if isinstance(getattr(icc, "copy", None), _InlinerCopy):
        return True
    if getattr(icc, "copy", None) is not copy_module or not callable(getattr(worker, "inline_ir", None)):
        return False
    shim = _InlinerCopy(copy_module)
    worker.inline_ir = shim.sharing(worker.inline_ir)
    icc.copy = shim
    return True


#: Whether numba's inliner shares one memo per inlined call (:func:`_share_inlined_copies`).
INLINED_COPIES_SHARED = _share_inlined_copies()


def batch_kernel(fn=None, *, disjoint=False, **options):
    """``@batch_kernel`` or ``@batch_kernel(error_model="numpy", ...)``: ``numba.njit``
    with ``cache=True`` and without the runtime (no reference counting, no
    allocation; see the module docstring).

    ``disjoint=True`` promises that no two arrays the kernel is given share memory
    that it writes (separate rows of one table, separate arrays), declared to LLVM as
    ``noalias`` (:data:`LLVM_OPTIONS`); a caller that broke the promise would get wrong
    results, not an error."""
    opts = {"cache": True, "_nrt": False, **options}
    if disjoint:
        opts["_noalias"] = True
    if fn is None:
        return njit(**opts)
    return njit(**opts)(fn)


# ------------------------------------------------------------------ tasks ---
#
# The tile tracers' renders run on threads of their own rather than in a ``prange`` loop.
# numba compiles a parallel loop's body as a function of its own and then optimises
# the loop's module again with every function the body calls linked in: for a tracer
# that is its whole call tree, optimised twice more, a large part of its cold compile.
# A task loop (:func:`take_task` in a ``nogil`` function, :func:`run_tasks` starting
# it on every thread) is a plain loop, and hands out the tasks dynamically as
# ``prange`` with a chunk size of one was meant to.
#
# The arrays a task loop is given keep their reference counts (numba's gufunc hands a
# ``prange`` body its arrays without them), so a loop whose tasks create array views of
# the shared arrays at a fine grain (a view per ray) makes both threads update the same
# counters atomically: such loops stay ``prange`` (distributed's rows and packet tiles,
# which take a view per pixel or per packet ray).  The tile tracers' per-ray work is in
# batch kernels, which count no references.


@intrinsic
def take_task(typingctx, queue):
    """The next task number of ``queue`` (a 1-D int64 array whose element 0 counts the
    tasks taken): an atomic fetch-and-add of one (LLVM ``atomicrmw``), so each number goes
    to exactly one of the threads that share the queue."""
    if not (isinstance(queue, types.Array) and queue.ndim == 1 and queue.dtype == types.int64):
        return None

    def codegen(context, builder, sig, args):
        aryty = sig.args[0]
        ary = context.make_array(aryty)(context, builder, args[0])
        ptr = cgutils.get_item_pointer(context, builder, aryty, ary,
                                       [context.get_constant(types.intp, 0)])
        return builder.atomic_rmw("add", ptr, context.get_constant(types.int64, 1), "monotonic")

    return types.int64(queue), codegen


class _Helper:
    """A helper thread of :func:`run_tasks`: runs the calls put in its inbox, one at a time,
    each with a :class:`concurrent.futures.Future` for its result.  ``tid`` is its
    kernel thread id, for :func:`_place`."""

    def __init__(self, k: int):
        self.inbox = queue.SimpleQueue()
        started = threading.Event()
        self.tid = None
        threading.Thread(target=self._loop, args=(started,), name=f"gibench-task-{k}",
                         daemon=True).start()
        started.wait()

    def _loop(self, started: threading.Event) -> None:
        self.tid = threading.get_native_id()
        started.set()
        while True:
            fn, args, future = self.inbox.get()
            if future.set_running_or_notify_cancel():
                try:
                    future.set_result(fn(*args))
                except BaseException as exc:     # handed to the caller of run_tasks
                    future.set_exception(exc)

    def submit(self, fn, *args) -> concurrent.futures.Future:
        future = concurrent.futures.Future()
        self.inbox.put((fn, args, future))
        return future


_helpers: list = []
_helpers_owner = None
_helpers_lock = threading.Lock()


def _threads(n: int) -> list:
    """``n`` helper threads of this process (made on first use, again after a fork)."""
    global _helpers, _helpers_owner
    with _helpers_lock:
        if _helpers_owner != os.getpid():
            _helpers, _helpers_owner = [], os.getpid()
        while len(_helpers) < n:
            _helpers.append(_Helper(len(_helpers)))
        return _helpers[:n]


def _current_cpu():
    """The C library's ``sched_getcpu`` (the processor the calling thread runs on), or
    None where there is none."""
    try:
        fn = ctypes.CDLL(None, use_errno=True).sched_getcpu
    except (AttributeError, OSError):
        return None
    fn.restype = ctypes.c_int
    fn.argtypes = []
    return fn


_getcpu = _current_cpu() if hasattr(os, "sched_setaffinity") else None


def _place(helpers: list) -> None:
    """Give each helper a processor of its own, other than the caller's, before it is
    woken: each helper's affinity is set to one processor of the caller's affinity mask
    that the caller is not running on.  Left to the scheduler (every helper's mask reset
    to the caller's) where the mask has too few processors or the platform cannot pin.

    Why: a woken thread can be queued on the processor of the thread that woke it, and
    the caller is then busy in the kernel on that processor, so the helper waits for
    its time slice or for the load balancer to move it, a wait as long as a small
    render.  OpenMP places its threads likewise on request (``OMP_PROC_BIND``).  The
    caller itself is not pinned, and the task queue still balances the work if another
    process holds a helper's processor."""
    if _getcpu is None or not helpers:
        return
    try:
        allowed = os.sched_getaffinity(0)
        here = _getcpu()
        others = sorted(allowed - {here})
        if here < 0 or len(others) < len(helpers):
            for h in helpers:
                os.sched_setaffinity(h.tid, allowed)
            return
        for h, cpu in zip(helpers, others):
            os.sched_setaffinity(h.tid, {cpu})
    except OSError:                 # a processor taken offline, a sandbox refusing: unplaced
        return


def run_tasks(kernel, *args):
    """Run ``kernel(*args, queue)`` on ``numba.get_num_threads()`` threads at once (the
    caller's and helpers, each helper on a processor of its own, :func:`_place`), all
    sharing one new task queue: the kernel, compiled with ``nogil=True``, takes task
    numbers with :func:`take_task` until they run out, so each task runs once, on
    whichever thread is free.  Returns once every thread is done; an exception raised
    on any thread is raised here (the caller's first), after all of them have stopped
    writing."""
    if not kernel.targetoptions.get("nogil"):
        raise TypeError(f"run_tasks: {kernel.py_func.__name__} must be compiled with nogil=True")
    tasks = np.zeros(1, np.int64)
    helpers = _threads(numba.get_num_threads() - 1)
    _place(helpers)
    futures = [h.submit(kernel, *args, tasks) for h in helpers]
    try:
        kernel(*args, tasks)
    finally:
        concurrent.futures.wait(futures)
    for f in futures:
        f.result()


@njit(cache=True)
def task_stride(n):
    """A stride s, coprime with ``n``, near n/φ (φ the golden ratio): iteration c of
    ``prange(n)`` runs task c·s mod n (:func:`interleaved`), a bijection of 0..n−1.

    numba's default schedule hands each thread one contiguous block of the iterations;
    with tasks in image order (pixels, chunks of eye rays) one thread would get the
    top of the image — often the cheap sky — and another the bottom.  The golden-ratio
    stride (a Weyl sequence) spreads every run of consecutive iterations over the whole
    image, whatever the thread count.  Each task's result does not depend on the thread
    that runs it."""
    if n <= 2:
        return 1
    s = int(n * 0.6180339887498949)
    while s > 1 and math.gcd(s, n) != 1:
        s -= 1
    return max(s, 1)


@njit(inline="always", cache=True)
def interleaved(c, n, stride):
    """The task of iteration ``c`` of ``prange(n)`` with :func:`task_stride`'s ``stride``."""
    return (c * stride) % n
