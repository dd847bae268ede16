"""Owen-scrambled Sobol points for the numba kernels.

The Sobol sequence (Sobol 1967) in base 2: point ``i`` of dimension ``d`` is
the XOR of the generator columns ``V_d[k]`` for every set bit ``k`` of ``i``.
Dimension 0 is the van der Corput sequence (``V_0[k] = 2**(31-k)``); the
others come from a primitive polynomial of degree ``s`` over GF(2) with
coefficients ``a`` and initial direction numbers ``m_1..m_s`` (Joe & Kuo
2008, the ``new-joe-kuo-6.21201`` table; :data:`JOE_KUO` holds its first
rows) through the recurrence (Bratley & Fox 1988)

    m_k = 2 a_1 m_{k-1} ^ 4 a_2 m_{k-2} ^ ... ^ 2^{s-1} a_{s-1} m_{k-s+1}
          ^ 2^s m_{k-s} ^ m_{k-s},      V[k-1] = m_k << (32 - k).

Dimensions 0 and 1 together are a (0, 2)-sequence: every block of ``2**m``
consecutive points (starting at a multiple of ``2**m``) puts exactly one point
in each elementary interval ``[a/2^j, (a+1)/2^j) x [b/2^(m-j), (b+1)/2^(m-j))``.

Randomisation (Burley 2020, "Practical Hash-based Owen Scrambling", JCGT
9(4)):

* the *value* is Owen-scrambled (each bit flipped by a hash of the bits above
  it) with the Laine–Karras permutation applied to the bit-reversed value
  (``nested_uniform_scramble``); this keeps every elementary-interval property
  and makes each point uniform on [0, 1);
* the *index* is shuffled with the same nested scramble, a permutation of
  every aligned block ``[k 2^m, (k+1) 2^m)``, so the first ``2**m`` indices of
  any seed still form a (0, m, 2)-net.

:func:`sample_2d` is the padded form a tracer uses (as Burley §4 and pbrt-v4's
``PaddedSobolSampler``): each 2D pair ``pair`` (lens, time/light, BSDF, ...)
takes Sobol dimensions (0, 1) with its own index shuffle and value scrambles
seeded by ``hash(seed, pair)``, so every pair is a scrambled (0, 2)-sequence
and different pairs are decorrelated.  :func:`sobol_point` gives the
full-dimensional (unpadded) Sobol point, scrambled per dimension.
:func:`sample_1d_seeded` and :func:`sample_2d_seeded` take their scramble seeds
ready-made (:func:`dimension_seed`, one 32-bit hash per seed), for a kernel that
draws many dimensions per sample in vector lanes (path's vertices).

Limits: 2**32 points per sequence; :data:`JOE_KUO` holds
:data:`MAX_DIMENSIONS` dimensions (padding needs only two); points are float64
with 32 significant bits.  The tracers draw from it with ``sampler=sobol``
(pixel positions, light samples, every number of path's vertices; every
dimension of ``distributed``, through :mod:`impl.samplers`).

References
----------
.. [1] I. M. Sobol, "On the distribution of points in a cube and the
   approximate evaluation of integrals", USSR Comput. Math. Math. Phys. 7(4), 1967.
.. [2] S. Joe and F. Y. Kuo, "Constructing Sobol sequences with better
   two-dimensional projections", SIAM J. Sci. Comput. 30(5), 2008.
.. [3] B. Burley, "Practical Hash-based Owen Scrambling", JCGT 9(4), 2020.
.. [4] S. Laine and T. Karras, "Stratified sampling for stochastic transparency",
   EGSR 2011 (the multiply-xor permutation).
.. [5] A. B. Owen, "Randomly permuted (t,m,s)-nets and (t,s)-sequences", 1995.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

__all__ = ["JOE_KUO", "MAX_DIMENSIONS", "generator_matrices", "sobol_uint", "sobol_point",
           "sample_1d", "sample_2d", "pair_hashes", "sample_2d_hashed", "samples_2d",
           "dimension_seed", "sample_1d_seeded", "sample_2d_seeded",
           "sobol_points", "nested_uniform_scramble", "pixel_seed"]

#: First rows of Joe & Kuo's ``new-joe-kuo-6.21201`` table (dimension 2 onwards, as
#: ``(s, a, (m_1, ..., m_s))``); dimension 1 (van der Corput) needs none.
JOE_KUO = (
    (1, 0, (1,)),
    (2, 1, (1, 3)),
    (3, 1, (1, 3, 1)),
    (3, 2, (1, 1, 1)),
    (4, 1, (1, 1, 3, 3)),
    (4, 4, (1, 3, 5, 13)),
    (5, 2, (1, 1, 5, 5, 17)),
    (5, 4, (1, 1, 5, 5, 5)),
    (5, 7, (1, 1, 7, 11, 19)),
    (5, 11, (1, 1, 5, 1, 1)),
    (5, 13, (1, 1, 1, 3, 11)),
    (5, 14, (1, 3, 5, 5, 31)),
    (6, 1, (1, 3, 3, 9, 7, 49)),
    (6, 13, (1, 1, 1, 15, 21, 21)),
    (6, 16, (1, 3, 1, 13, 27, 49)),
)
MAX_DIMENSIONS = len(JOE_KUO) + 1
_MASK = np.uint64(0xFFFFFFFF)


def generator_matrices(ndim: int = MAX_DIMENSIONS) -> np.ndarray:
    """The Sobol generator columns, uint32 ``(ndim, 32)``: ``V[d, k]`` is XORed into
    point ``i`` of dimension ``d`` when bit ``k`` of ``i`` is set."""
    if not 1 <= ndim <= MAX_DIMENSIONS:
        raise ValueError(f"ndim must be in 1..{MAX_DIMENSIONS}, got {ndim}")
    v = np.zeros((ndim, 32), dtype=np.uint64)
    v[0] = [1 << (31 - k) for k in range(32)]
    for d in range(1, ndim):
        s, a, m_init = JOE_KUO[d - 1]
        m = list(m_init)
        for k in range(s, 32):
            # m_k from the s previous ones (0-based: m[k] from m[k-1] .. m[k-s])
            new = m[k - s] ^ (m[k - s] << s)
            for j in range(1, s):
                if (a >> (s - 1 - j)) & 1:
                    new ^= m[k - j] << j
            m.append(new)
        v[d] = [m[k] << (31 - k) for k in range(32)]
    return (v & 0xFFFFFFFF).astype(np.uint32)


_V = generator_matrices()


def _byte_tables(columns: np.ndarray) -> np.ndarray:
    """``T[b, j]``: the XOR of the generator columns ``columns[8b + k]`` over the set
    bits k of byte value j, uint32 ``(4, 256)``: a point of one dimension is then
    ``T[0, i & 255] ^ T[1, (i >> 8) & 255] ^ T[2, ...] ^ T[3, ...]`` (four loads
    instead of a loop over the index's 32 bits)."""
    t = np.zeros((4, 256), dtype=np.uint32)
    for b in range(4):
        for j in range(256):
            x = 0
            for k in range(8):
                if (j >> k) & 1:
                    x ^= int(columns[8 * b + k])
            t[b, j] = x
    return t


#: Byte tables of Sobol dimension 1 (dimension 0 is the bit reversal of the index).
_T1 = _byte_tables(_V[1])


# --------------------------------------------------------------------- hashing


@njit(inline="always", cache=True)
def _mix32(x):
    """Wellons' ``lowbias32`` integer hash (32-bit in uint64, masked)."""
    x = x & _MASK
    x ^= x >> np.uint64(16)
    x = (x * np.uint64(0x7FEB352D)) & _MASK
    x ^= x >> np.uint64(15)
    x = (x * np.uint64(0x846CA68B)) & _MASK
    x ^= x >> np.uint64(16)
    return x


_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


@njit(inline="always", cache=True)
def _mix64(x):
    """The SplitMix64 finaliser (Steele et al. 2014): a 64-bit bijective hash."""
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


@njit(inline="always", cache=True)
def _hash2(a, b):
    """A 32-bit hash of two non-negative integers."""
    return _mix32(_mix32(np.uint64(a)) ^ (np.uint64(b) * np.uint64(0x9E3779B9) & _MASK)
                  ^ np.uint64(0x85EBCA6B))


def _low32(context, builder, t, v):
    """An integer argument's low 32 bits as an LLVM i32."""
    i32 = ir.IntType(32)
    if t.bitwidth > 32:
        return builder.trunc(v, i32)
    return v if t.bitwidth == 32 else builder.zext(v, i32)


@intrinsic
def _reverse32(typingctx, x):
    """The bit reversal of the low 32 bits of ``x``, as a uint64 below 2**32.  LLVM's
    ``bitreverse`` on 32-bit lanes: vectorised, a byte-table shuffle (or one GF(2)
    affine instruction where the target has GFNI) per vector instead of five rounds
    of masked shifts in 64-bit lanes."""
    if not isinstance(x, types.Integer):
        return None

    def codegen(context, builder, sig, args):
        i32 = ir.IntType(32)
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(i32, [i32]),
                                            "llvm.bitreverse.i32")
        r = builder.call(fn, [_low32(context, builder, sig.args[0], args[0])])
        return builder.zext(r, ir.IntType(64))

    return types.uint64(x), codegen


@intrinsic
def _laine_karras(typingctx, x, seed):
    """Burley 2020, listing 2 (the Laine–Karras permutation): output bit k depends only
    on input bits <= k.  Arithmetic modulo 2**32 on the low 32 bits of ``x`` and
    ``seed``, in 32-bit lanes (the values the 64-bit form masked to 32 bits); the
    result a uint64 below 2**32."""
    if not (isinstance(x, types.Integer) and isinstance(seed, types.Integer)):
        return None

    def codegen(context, builder, sig, args):
        i32 = ir.IntType(32)
        v = builder.add(_low32(context, builder, sig.args[0], args[0]),
                        _low32(context, builder, sig.args[1], args[1]))
        for c in (0x6C50B47C, 0xB82F1E52, 0xC7AFE638, 0x8D22F6E6):
            v = builder.xor(v, builder.mul(v, ir.Constant(i32, c)))
        return builder.zext(v, ir.IntType(64))

    return types.uint64(x, seed), codegen


@intrinsic
def _lowbias32(typingctx, x):
    """:func:`_mix32` (Wellons' ``lowbias32``) in 32-bit lanes: the same values for the
    low 32 bits of ``x``, two 32-bit multiplies where the masked 64-bit form vectorises
    to 64-bit ones.  The result a uint64 below 2**32."""
    if not isinstance(x, types.Integer):
        return None

    def codegen(context, builder, sig, args):
        i32 = ir.IntType(32)
        v = _low32(context, builder, sig.args[0], args[0])
        for shift, mul in ((16, 0x7FEB352D), (15, 0x846CA68B)):
            v = builder.xor(v, builder.lshr(v, ir.Constant(i32, shift)))
            v = builder.mul(v, ir.Constant(i32, mul))
        v = builder.xor(v, builder.lshr(v, ir.Constant(i32, 16)))
        return builder.zext(v, ir.IntType(64))

    return types.uint64(x), codegen


@njit(inline="always", cache=True)
def dimension_seed(seed, dim):
    """A 32-bit scramble seed for dimension ``dim`` of the sequence of the 64-bit ``seed``
    (a pixel's :func:`pixel_seed`): :func:`_lowbias32` of the seed's two halves folded
    together plus ``dim`` times the 32-bit golden ratio.  Cheaper than :func:`_hash2`
    (one hash, 32-bit lanes), for callers drawing many dimensions per sample."""
    s = np.uint64(seed)
    return _lowbias32((s ^ (s >> np.uint64(32))) + np.uint64(dim) * np.uint64(0x9E3779B9))


@njit(inline="always", cache=True)
def sample_1d_seeded(index, s_index, s_value):
    """A padded 1-D sample from two 32-bit seeds (:func:`dimension_seed`): point ``index``
    of the van der Corput sequence, its index shuffled by a nested uniform scramble seeded
    by ``s_index`` and its value by one seeded by ``s_value``.  The first 2**m indices
    give one point in each interval [j/2**m, (j+1)/2**m): stratified, each uniform."""
    i = _reverse32(_laine_karras(_reverse32(np.uint64(index)), s_index))
    return float(_reverse32(_laine_karras(i, s_value))) * _INV32


@njit(inline="always", cache=True)
def sample_2d_seeded(index, s_index, s_u, s_v):
    """:func:`sample_2d_hashed` from three 32-bit seeds (:func:`dimension_seed`): the
    index shuffle's and the two coordinates' value scrambles.  The first 2**m indices are
    a scrambled (0, m, 2)-net."""
    return sample_2d_hashed(index, (np.uint64(s_u) << np.uint64(32)) | np.uint64(s_index),
                            np.uint64(s_v) << np.uint64(32))


@njit(inline="always", cache=True)
def nested_uniform_scramble(x, seed):
    """Owen scrambling of a 32-bit value: bit ``j`` (from the top) flipped by a hash of
    the bits above it and ``seed`` (Burley 2020, listing 3)."""
    return _reverse32(_laine_karras(_reverse32(np.uint64(x)), _mix32(np.uint64(seed))))


# ---------------------------------------------------------------------- points


@njit(inline="always", cache=True)
def _sobol(v, index, dim):
    x = np.uint64(0)
    i = np.uint64(index) & _MASK
    k = 0
    while i:
        if i & np.uint64(1):
            x ^= np.uint64(v[dim, k])
        i >>= np.uint64(1)
        k += 1
    return x


@njit(cache=True)
def sobol_uint(index, dim):
    """The unscrambled Sobol point ``index`` of dimension ``dim`` as a 32-bit integer
    (``value / 2**32`` in [0, 1))."""
    return _sobol(_V, index, dim)


_INV32 = 1.0 / 4294967296.0


@njit(inline="always", cache=True)
def _sobol1(i):
    """Unscrambled Sobol dimension 1 of the 32-bit index ``i``, four byte-table lookups
    (:data:`_T1`) instead of a loop over its bits."""
    return (np.uint64(_T1[0, i & np.uint64(255)]) ^ np.uint64(_T1[1, (i >> np.uint64(8)) & np.uint64(255)])
            ^ np.uint64(_T1[2, (i >> np.uint64(16)) & np.uint64(255)]) ^ np.uint64(_T1[3, i >> np.uint64(24)]))


@njit(inline="always", cache=True)
def sobol_point(index, dim, seed):
    """Dimension ``dim`` of Owen-scrambled Sobol point ``index`` (float64 in [0, 1)).

    One index shuffle for the whole point (seeded by ``seed``), one value
    scramble per dimension: all dimensions of a point share it, so this is the
    full ``MAX_DIMENSIONS``-dimensional sequence.  Dimensions 0 and 1 are computed
    as the bit reversal and from byte tables (the same values as the bit loop).
    """
    i = nested_uniform_scramble(np.uint64(index), _hash2(seed, 0xFFFFFFFF))
    if dim == 0:
        x = _reverse32(i)
    elif dim == 1:
        x = _sobol1(i)
    else:
        x = _sobol(_V, i, dim)
    return float(nested_uniform_scramble(x, _hash2(seed, dim))) * _INV32


@njit(inline="always", cache=True)
def sample_1d(dim, index, seed):
    """Padded 1D sample: the scrambled van der Corput point ``index`` of 1D dimension
    ``dim`` (own index shuffle and scramble per ``(seed, dim)``).  Sobol dimension 0
    of point i is the bit reversal of i, computed as such."""
    h = _hash2(seed, np.uint64(2) * np.uint64(dim) + np.uint64(0x10000))
    i = nested_uniform_scramble(np.uint64(index), h)
    return float(nested_uniform_scramble(_reverse32(i), _mix32(h + np.uint64(1)))) * _INV32


@njit(inline="always", cache=True)
def sample_2d(pair, index, seed):
    """Padded 2D sample ``(u, v)``: Sobol dimensions (0, 1) with an index shuffle and two
    value scrambles seeded by ``(seed, pair)``.  For every ``pair`` and ``seed`` the
    points ``index = 0 .. 2**m - 1`` are a scrambled (0, m, 2)-net.

    The three 32-bit scramble seeds are the two halves of one SplitMix64 hash of
    ``(seed, pair)`` and the upper half of a second one (a short dependency chain: a
    tracer draws a pair per pixel sample and light sample).  The shuffled index is
    i = rev(LK(rev(index))); dimension 0 of point i is rev(i), so that reversal pair
    cancels, and dimension 1 comes from byte tables."""
    h, h2 = pair_hashes(pair, seed)
    return sample_2d_hashed(index, h, h2)


@njit(inline="always", cache=True)
def pair_hashes(pair, seed):
    """The two 64-bit hashes of ``(seed, pair)`` that scramble :func:`sample_2d`'s points:
    they depend on neither the index, so a caller drawing many indices of one pair and
    seed (a pixel's samples) computes them once (:func:`sample_2d_hashed`)."""
    h = _mix64(np.uint64(seed) + (np.uint64(2) * np.uint64(pair) + np.uint64(1)) * _GOLDEN)
    return h, _mix64(h + _GOLDEN)


@njit(inline="always", cache=True)
def sample_2d_hashed(index, h, h2):
    """:func:`sample_2d` from its :func:`pair_hashes` ``h``, ``h2``: the same bits."""
    li = _laine_karras(_reverse32(np.uint64(index)), h & _MASK)
    i = _reverse32(li)
    x1 = _sobol1(i)
    u = _reverse32(_laine_karras(_reverse32(li), h >> np.uint64(32)))
    v = _reverse32(_laine_karras(_reverse32(x1), h2 >> np.uint64(32)))
    return float(u) * _INV32, float(v) * _INV32


@njit(inline="always", cache=True)
def pixel_seed(x, y, seed):
    """A per-pixel sequence seed (64 bits): pixels draw decorrelated scrambles of one
    sequence.  Two SplitMix64 finaliser rounds over (seed, x, y)."""
    return _mix64(_mix64(np.uint64(seed) * _GOLDEN + np.uint64(x)) + np.uint64(y) * _GOLDEN)


@njit(cache=True)
def _samples_2d(n, pair, seed, start, out):
    for k in range(n):
        u, v = sample_2d(pair, start + k, seed)
        out[k, 0] = u
        out[k, 1] = v


@njit(cache=True)
def _points(n, ndim, seed, start, out):
    for k in range(n):
        for d in range(ndim):
            out[k, d] = sobol_point(start + k, d, seed)


def _check(n, seed, start):
    if n < 0 or start < 0 or n + start > 2 ** 32:
        raise ValueError(f"need 0 <= start and start + n <= 2**32, got start={start}, n={n}")
    if seed < 0:
        raise ValueError(f"seed must be non-negative, got {seed}")


def samples_2d(n: int, *, pair: int = 0, seed: int = 0, start: int = 0) -> np.ndarray:
    """Points ``start .. start + n - 1`` of :func:`sample_2d`, float64 ``(n, 2)``."""
    _check(n, seed, start)
    out = np.empty((n, 2), dtype=np.float64)
    _samples_2d(n, pair, seed, start, out)
    return out


def sobol_points(n: int, ndim: int, *, seed: int = 0, start: int = 0) -> np.ndarray:
    """Points ``start .. start + n - 1`` of :func:`sobol_point`, float64 ``(n, ndim)``."""
    _check(n, seed, start)
    if not 1 <= ndim <= MAX_DIMENSIONS:
        raise ValueError(f"ndim must be in 1..{MAX_DIMENSIONS}, got {ndim}")
    out = np.empty((n, ndim), dtype=np.float64)
    _points(n, ndim, seed, start, out)
    return out
