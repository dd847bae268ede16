"""Solvers of the radiosity system (thesis 3.2.3, 3.3):

    B_i = E_i + ρ_i Σ_j F_ij B_j ,   i.e.  (I − ρF) B = E ,

per colour channel (ρ a diagonal matrix of the patch reflectances).  Because
ρ < 1 and the rows of F sum to at most 1, the matrix is strictly diagonally
dominant, so Jacobi and Gauss–Seidel converge; the error after k steps falls
like (max ρ)^k in the worst case (a closed white box).

===============  =============================================================
solver           iteration
===============  =============================================================
``direct``       dense LU (``numpy.linalg.solve``): the reference solution
``jacobi``       B ← E + ρ F B — iteration k holds exactly the light of paths
                 with ≤ k bounces (the Neumann series), which is what
                 ``max_bounces`` uses to mimic a depth-limited path tracer
``gauss-seidel`` the same, updating B_i in place (new values used at once)
``progressive``  Cohen et al. 1988: repeatedly shoot the patch with the most
                 unshot power A_i ΔB_i: B_j += ρ_j F_ji ΔB_i for all j.  The
                 column F_{·i} is used directly (no reciprocity assumed), so
                 the fixed point is that of the same system.  An ambient term
                 ρ_i · R Σ A_k ΔB_k / Σ A_k, R = 1 / (1 − ρ_avg), is returned
                 for display of partial solutions.
===============  =============================================================

Convergence is measured by the relative residual ‖E + ρFB − B‖₂ / ‖E‖₂
(all channels), recorded per iteration with its wall-clock time.  One
"iteration" of progressive refinement is N shots (the work of one sweep).
For Jacobi the residual is free (B^{k+1} − B^k is the residual of B^k, and the
returned iterate is the one whose residual stopped the loop); for Gauss–Seidel and
progressive refinement it costs one extra matrix–vector product per
iteration, included in the times.  The error is bounded by the residual:
‖B − B*‖ ≤ ‖r‖ / (1 − max ρ) in the ∞-norm, so a tight tolerance is needed
when ρ → 1.

Divergence.  ρ F is non-negative, so by Perron–Frobenius its spectral radius
λ satisfies min_i (ρFx)_i / x_i ≤ λ ≤ max_i (ρFx)_i / x_i for every positive
x (the Collatz–Wielandt bounds; x = 1 gives the row sums).  The Neumann
series, Jacobi, Gauss–Seidel (Stein–Rosenberg: for a non-negative splitting
it converges exactly when Jacobi does) and progressive refinement all
converge iff λ < 1; with λ ≥ 1 the "solution" is not a radiosity (the direct
solve returns negative or enormous values).  Closed form factors (hemicube,
contour, Monte Carlo) have row sums ≤ 1 and ρ < 1, so λ < 1 at a glance; an
approximation such as the point form factor can make rows of ρF sum to more
than 1.  :func:`check_convergent` then tightens the bounds by power
iteration and refuses the system with one :class:`~core.errors.ParamError`
line naming λ's bound and the patches whose rows exceed 1, instead of
returning inf or nan.

Reference: M. F. Cohen, S. E. Chen, J. R. Wallace, D. P. Greenberg, "A
progressive refinement approach to fast radiosity image generation",
SIGGRAPH 1988; Cohen & Wallace (1993), ch. 5.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np
from numba import njit
from core.errors import ParamError

__all__ = ["SOLVERS", "SolveResult", "solve", "residual", "neumann", "check_convergent",
           "spectral_bounds"]

SOLVERS = ("jacobi", "gauss-seidel", "progressive", "direct")


class SolveResult(NamedTuple):
    B: np.ndarray               # (N, 3) radiosity
    ambient: np.ndarray         # (N, 3) display ambient term (progressive; zeros otherwise)
    iterations: int             # sweeps (progressive: shots / N, rounded up)
    shots: int                  # progressive: patches shot
    residuals: np.ndarray       # relative residual after each iteration (first: of B = E)
    times: np.ndarray           # seconds since the start at each residual
    seconds: float
    converged: bool
    solver: str

    def __repr__(self) -> str:
        return (f"SolveResult({self.solver}, N={len(self.B)}, iterations={self.iterations}, "
                f"residual={self.residuals[-1]:.3g}, {self.seconds * 1e3:.1f} ms, converged={self.converged})")


def residual(F, rho, E, B) -> float:
    """‖E + ρFB − B‖₂ / ‖E‖₂ over all channels."""
    r = E + rho * (F @ B) - B
    return float(np.linalg.norm(r) / max(np.linalg.norm(E), 1e-300))


def neumann(F, rho, E, bounces: int) -> np.ndarray:
    """Σ_{k=0}^{bounces} (ρF)^k E: radiosity of paths with at most ``bounces`` reflections."""
    B = E.copy()
    for _ in range(bounces):
        B = E + rho * (F @ B)
    return B


def spectral_bounds(A: np.ndarray, *, iterations: int = 200, rtol: float = 1e-3) -> tuple[float, float]:
    """Collatz–Wielandt bounds (lo, hi) on the spectral radius of a non-negative
    square matrix ``A``: power iteration from x = 1, after each step
    lo = min_i (Ax)_i / x_i and hi = max_i (Ax)_i / x_i over the x_i > 0.

    Stops when the bounds decide the comparison with 1 (lo ≥ 1 or hi < 1), when
    hi − lo ≤ ``rtol`` · hi, or after ``iterations`` steps.  The upper bound is
    rigorous for any positive x; the lower bound is the smallest ratio over the
    support of x (rows with x_i = 0 are ignored, which keeps it a lower bound of
    the spectral radius of the block that x lives on, hence of A's)."""
    x = np.ones(A.shape[0])
    lo, hi = 0.0, np.inf
    for _ in range(iterations):
        y = A @ x
        pos = x > 0
        if not pos.any():
            return 0.0, 0.0
        ratio = y[pos] / x[pos]
        lo, hi = max(lo, float(ratio.min())), min(hi, float(ratio.max()))
        if lo >= 1.0 or hi < 1.0 or hi - lo <= rtol * hi:
            break
        s = y.max()
        if s <= 0.0:
            return 0.0, 0.0
        x = y / s
    return lo, hi


def check_convergent(F, rho, *, source: str = "") -> None:
    """Raise :class:`ParamError` when the iteration B ← E + ρFB diverges, i.e. the
    spectral radius of ρF (per colour channel) is ≥ 1.  ``source`` names where F
    came from (e.g. ``"formfactor=point"``) in the message.

    Cheap when every row of ρF sums to ≤ 1 (one pass over F); otherwise the
    Collatz–Wielandt bounds of :func:`spectral_bounds` decide.  A radius that the
    bounds cannot separate from 1 within their iterations is let through (the
    iteration then stalls at ``max_iter`` with ``converged = False``)."""
    F = np.asarray(F, dtype=np.float64)
    rho = np.asarray(rho, dtype=np.float64)
    rows = F.sum(axis=1)
    for c, name in enumerate("RGB"):
        sums = rho[:, c] * rows
        if sums.max() <= 1.0:
            continue
        lo, hi = spectral_bounds(rho[:, c, None] * F)
        if lo < 1.0:
            continue
        over = np.flatnonzero(sums > 1.0)
        worst = int(over[np.argmax(sums[over])])
        shown = ", ".join(str(int(i)) for i in over[:8]) + (", ..." if len(over) > 8 else "")
        raise ParamError(
            f"radiosity: the system B = E + ρFB{' (' + source + ')' if source else ''} has no "
            f"convergent iteration: the spectral radius of ρF (channel {name}) is >= {lo:.4g} "
            f"(Collatz-Wielandt bound) because rows of ρF sum to more than 1 at {len(over)} of "
            f"{len(sums)} patches ({shown}; max {sums[worst]:.4g} at patch {worst}); these form "
            "factors do not close (Σ_j F_ij > 1); contour, hemicube and hemicube-zbuffer do")


@njit(cache=True)
def _gs_sweep(F, rho, E, B):
    N = B.shape[0]
    for i in range(N):
        s0 = s1 = s2 = 0.0
        row = F[i]
        for j in range(N):
            if j != i:
                f = row[j]
                s0 += f * B[j, 0]
                s1 += f * B[j, 1]
                s2 += f * B[j, 2]
        d = row[i]
        B[i, 0] = (E[i, 0] + rho[i, 0] * s0) / (1.0 - rho[i, 0] * d)
        B[i, 1] = (E[i, 1] + rho[i, 1] * s1) / (1.0 - rho[i, 1] * d)
        B[i, 2] = (E[i, 2] + rho[i, 2] * s2) / (1.0 - rho[i, 2] * d)


@njit(cache=True)
def _shoot(FT, rho, area, B, dB, n_shots):
    """``n_shots`` progressive-refinement steps; returns the shots done (< n_shots when
    nothing is left to shoot)."""
    N = B.shape[0]
    for s in range(n_shots):
        best = -1.0
        i = -1
        for k in range(N):
            p = area[k] * (dB[k, 0] + dB[k, 1] + dB[k, 2])
            if p > best:
                best = p
                i = k
        if best <= 0.0:
            return s
        u0, u1, u2 = dB[i, 0], dB[i, 1], dB[i, 2]
        dB[i, 0] = dB[i, 1] = dB[i, 2] = 0.0
        col = FT[i]                       # F_{ji} for all j
        for j in range(N):
            f = col[j]
            if f != 0.0:
                a0, a1, a2 = rho[j, 0] * f * u0, rho[j, 1] * f * u1, rho[j, 2] * f * u2
                B[j, 0] += a0
                B[j, 1] += a1
                B[j, 2] += a2
                dB[j, 0] += a0
                dB[j, 1] += a1
                dB[j, 2] += a2
    return n_shots


def solve(F, rho, E, area, solver: str = "gauss-seidel", *, tol: float = 1e-8,
          max_iter: int = 10000, source: str = "") -> SolveResult:
    """Solve (I − ρF)B = E with ``solver``; iterate until the relative residual ≤ ``tol``
    or ``max_iter`` iterations.

    Parameters
    ----------
    F : (N, N) form factors (row i from patch i)
    rho, E : (N, 3) reflectance and emitted radiosity
    area : (N,) patch areas (progressive refinement's shooting order, ambient)
    source : where F came from, named in the divergence error

    Raises
    ------
    ParamError
        when the spectral radius of ρF is ≥ 1 (:func:`check_convergent`): no
        solver returns a radiosity then, so none is run.
    """
    if solver not in SOLVERS:
        raise ParamError(f"radiosity: unknown solver {solver!r} (valid: {', '.join(SOLVERS)})")
    if tol <= 0 or max_iter < 1:
        raise ParamError(f"radiosity: tol must be > 0 and max_iter >= 1, got {tol}, {max_iter}")
    F = np.ascontiguousarray(F, dtype=np.float64)
    rho = np.ascontiguousarray(rho, dtype=np.float64)
    E = np.ascontiguousarray(E, dtype=np.float64)
    N = len(E)
    check_convergent(F, rho, source=source)
    t0 = time.perf_counter()
    ambient = np.zeros_like(E)
    res, times = [residual(F, rho, E, E)], [time.perf_counter() - t0]
    shots = 0
    if solver == "direct":
        B = np.empty_like(E)
        for c in range(3):
            B[:, c] = np.linalg.solve(np.eye(N) - rho[:, c, None] * F, E[:, c])
        res.append(residual(F, rho, E, B))
        times.append(time.perf_counter() - t0)
        it = 1
    elif solver == "jacobi":
        # B^{k+1} − B^k = E + ρF B^k − B^k is exactly the residual of B^k, so each
        # step computes the residual of the iterate it holds; the loop stops on it,
        # returns that iterate, and its residual (res[-1]) alone decides ``converged``.
        B = E.copy()
        it = 0
        normE = max(np.linalg.norm(E), 1e-300)
        res.clear()
        times.clear()
        while True:
            Bn = E + rho * (F @ B)
            res.append(float(np.linalg.norm(Bn - B) / normE))
            times.append(time.perf_counter() - t0)
            if res[-1] <= tol or it >= max_iter:
                break
            B = Bn
            it += 1
    elif solver == "gauss-seidel":
        B = E.copy()
        it = 0
        while res[-1] > tol and it < max_iter:
            _gs_sweep(F, rho, E, B)
            it += 1
            res.append(residual(F, rho, E, B))
            times.append(time.perf_counter() - t0)
    else:
        FT = np.ascontiguousarray(F.T)
        B, dB = E.copy(), E.copy()
        area = np.ascontiguousarray(area, dtype=np.float64)
        it = 0
        while res[-1] > tol and it < max_iter:
            done = _shoot(FT, rho, area, B, dB, N)
            shots += done
            it += 1
            res.append(float(np.linalg.norm(rho * (F @ dB)) / max(np.linalg.norm(E), 1e-300)))
            times.append(time.perf_counter() - t0)
            if done < N:
                break
        # Ambient term (Cohen et al. 1988, §4): the unshot power spread evenly,
        # interreflected with the area-weighted mean reflectance.
        A = area.sum()
        rho_avg = (area[:, None] * rho).sum(axis=0) / A
        amb = (area[:, None] * dB).sum(axis=0) / A / (1.0 - rho_avg)
        ambient = rho * amb[None, :]
    seconds = time.perf_counter() - t0
    return SolveResult(B=B, ambient=ambient, iterations=it, shots=shots, residuals=np.asarray(res),
                       times=np.asarray(times), seconds=seconds, converged=bool(res[-1] <= tol),
                       solver=solver)
