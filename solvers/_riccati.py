r"""Infinite-horizon LQR: the discrete and continuous algebraic Riccati equations, by doubling.

**Infinite horizon, discrete** (:func:`dare`): the stabilizing solution ``P`` of

.. math::  P = A^\top P A - (A^\top P B + S^\top)(R + B^\top P B)^{-1}(B^\top P A + S) + Q

for the cost ``sum_t 0.5 (x'Qx + u'Ru) + u'Sx`` (scipy's ``solve_discrete_are(A, B, Q, R, s=S.T)``),
with the gain ``K = (R + B'PB)^{-1} (B'PA + S)`` **applied with a minus sign, ``u = -K x``**
(the scipy / python-control / textbook convention of the reference data). The cross term is
removed by the substitution ``u = v - R^{-1} S x`` (``A -> A - B R^{-1} S``,
``Q -> Q - S' R^{-1} S``) and the equation, written as ``P = A' P (I + G P)^{-1} A + H`` with
``G = B R^{-1} B'``, is solved by the structure-preserving doubling algorithm (SDA; Chu, Fan & Lin,
2005)::

    W = I + G_k H_k
    A_{k+1} = A_k W^{-1} A_k
    G_{k+1} = G_k + A_k W^{-1} G_k A_k'
    H_{k+1} = H_k + A_k' H_k W^{-1} A_k            (H_0 = Q, G_0 = G, A_0 = A)

``H_k`` converges to ``P`` quadratically: its error is ``O(rho^(2^(k+1)))`` with ``rho`` the spectral
radius of the closed loop ``A - B K``, so a few (typically 5-12) iterations reach machine precision.
Each iteration costs one solve with ``2n`` right-hand sides (Gauss-Jordan with partial pivoting,
:func:`solvers._linalg.solve`: under ``vmap`` on XLA:CPU a third of the time of LAPACK's per-system LU) and a
few ``n x n`` products.

**Infinite horizon, continuous** (:func:`care`): the stabilizing solution of
``A'P + PA - (PB + S') R^{-1} (B'P + S) + Q = 0`` with ``K = R^{-1} (B'P + S)``, ``u = -K x``
(scipy's ``solve_continuous_are(A, B, Q, R, s=S.T)``). A Cayley transform with a shift
``gamma > 0`` maps the Hamiltonian's stable eigenvalues ``lambda`` to ``(lambda + gamma) /
(lambda - gamma)`` inside the unit disc and gives an equivalent discrete equation with the same
stabilizing solution, ``A_hat = I + 2 gamma W^{-1}``, ``G_hat = 2 gamma W^{-1} G A_g^{-T}``,
``H_hat = 2 gamma W^{-T} Q A_g^{-1}`` with ``A_g = A - gamma I`` and ``W = A_g + G A_g^{-T} Q``
(Chu, Fan & Lin's SDA for CAREs), which the same doubling iteration solves.

**Derivatives** of ``P`` (and so of ``K``) with respect to ``A, B, Q, R, S`` are exact, by implicit
differentiation: the iteration itself is not differentiated (it runs on
``lax.stop_gradient``-ed data) and a ``jax.custom_jvp`` gives the tangent ``dP`` as the solution of
the closed-loop Stein equation ``dP - A_cl' dP A_cl = E`` (discrete) or Lyapunov equation
``A_cl' dP + dP A_cl = -E`` (continuous), where ``A_cl = A - B K`` and
``E = dQ + K' dR K - dS' K - K' dS + (dA - dB K)' P A_cl + A_cl' P (dA - dB K)`` (discrete;
continuous: the last two terms are ``(dA - dB K)' P + P (dA - dB K)``). The envelope theorem
makes the terms in ``dK`` vanish. Those linear equations are solved by Smith's doubling (after a
Cayley transform in the continuous case) inside ``lax.custom_linear_solve`` with its transposed
solve, so forward mode (``jax.jvp``/``jacfwd``) and reverse mode (``jax.grad``) both work, to any
order (the tangent rule differentiates through itself, so Hessians are exact too).

Every function solves one problem and is pure, ``eqx.filter_jit``-ed and ``jax.vmap``-able; under
``vmap`` each element keeps its own ``result`` (``throw=False``, the default).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from ._checks import _all_finite, _amax, _as_float, _check_int, _check_shape, _common_dtype, _fmt, _sym
from ._iterate import Iteration, iterate
from ._linalg import matmul, solve
from ._results import RESULTS

__all__ = ["RiccatiSolution", "care", "dare"]

_STEIN_MAX_STEPS = 64  # doublings of Smith's iteration in the implicit derivative: 2^64 terms
#: Lanes of a batched doubling (:func:`solvers._lanes.while_loop`). A doubling step is one small solve and
#: six products of n x n blocks, a few microseconds a system, so the lanes' per-step cost of XLA:CPU
#: instructions weighs more than the steps that the slowest problem of a wide lane adds. Measured on the
#: 2-core CPU, 12 x 4 systems, ms per batch of 1024 / 10^4: 128 lanes 66 / 555, 512 lanes 61 / 480,
#: 1024 lanes 50 / 465; again with the Gauss-Jordan solve: 512 lanes 33 / 321-324, 1024 lanes 26-27 / 299-311,
#: 2048 lanes 27 / 337.
_DOUBLING_LANES = 1024


class RiccatiSolution(eqx.Module):
    """The stabilizing solution of an algebraic Riccati equation (:func:`dare`, :func:`care`).

    Attributes:
        P: ``[n, n]`` the symmetric stabilizing solution; the optimal cost from ``x0`` is
            ``0.5 x0' P x0`` for the costs ``0.5 (x'Qx + u'Ru) + u'Sx`` (per step or per unit time).
        K: ``[m, n]`` the optimal gain, applied as ``u = -K x`` (**minus** sign, as scipy and
            python-control): ``K = (R + B'PB)^{-1} (B'PA + S)`` (discrete) or
            ``K = R^{-1} (B'P + S)`` (continuous).
        result: :class:`~solvers.RESULTS`: ``successful``; ``no_stabilising_solution`` when the
            iteration produced a non-finite value (not stabilizable, R not positive definite,
            non-finite data, ...) or the converged iterate has a large Riccati residual;
            ``max_steps_reached`` when the iteration stayed finite but did not converge in
            ``max_steps`` (too few steps, or a closed-loop eigenvalue on or extremely close to the
            stability boundary). Per element under ``jax.vmap``.
        stats: arrays:

            - ``num_steps`` (int): doubling iterations performed.
            - ``residual``: ``max |F(P)|``, the largest entry of the Riccati residual.
    """

    P: Float[Array, "n n"]
    K: Float[Array, "m n"]
    result: RESULTS
    stats: dict[str, Array]


# --------------------------------------------------------------------------------------------
# The structure-preserving doubling algorithm (shared by dare and care).
# --------------------------------------------------------------------------------------------


class _Doubling(eqx.Module):
    """An SDA iterate ``(A_k, G_k, H_k)`` and whether the last doubling met the tolerance."""

    A: Float[Array, "n n"]
    G: Float[Array, "n n"]
    H: Float[Array, "n n"]
    converged: Bool[Array, ""]


def _sda(
    A0: Float[Array, "n n"],
    G0: Float[Array, "n n"],
    H0: Float[Array, "n n"],
    rtol: Float[Array, ""],
    atol: Float[Array, ""],
    max_steps: int,
    fixed_steps: bool,
) -> Iteration[_Doubling]:
    """Doubling for ``X = A' X (I + G X)^{-1} A + H``; ``H_k -> X``.

    Converged when the last increment of ``H`` satisfies ``|dH|_max <= atol + rtol |H|_max`` and
    ``|A_k|_max <= sqrt(rtol)``. The increment is computed directly (not as a difference), so
    it goes to zero with ``A_k`` instead of stalling at rounding level. The second test rejects
    a non-stabilizing fixed point (``A_k`` does not vanish when the closed loop is not stable,
    e.g. an unstable mode that ``B`` cannot reach and ``Q`` does not weight, where ``H`` never
    moves); it costs at most one more iteration in the stabilizing case, where ``A_k`` and the
    increments vanish together. The driver's non-finite guard stops the iteration at a
    non-finite iterate and keeps the last finite one (``Iteration.nonfinite``).
    """
    n = A0.shape[0]
    eye = jnp.eye(n, dtype=A0.dtype)
    a_tol = jnp.sqrt(rtol)

    def advance(c: _Doubling) -> _Doubling:
        W = eye + matmul(c.G, c.H)
        Z = solve(W, jnp.concatenate([c.A, c.G], axis=1))
        WA, WG = Z[:, :n], Z[:, n:]
        A1 = matmul(c.A, WA)
        G1 = _sym(c.G + matmul(matmul(c.A, WG), c.A.T))
        # A' as a copy: a dot that contracts its left operand's rows takes XLA:CPU's slow path (3x)
        At = jax.lax.optimization_barrier(c.A.T)
        dH = _sym(matmul(At, matmul(c.H, WA)))
        H1 = c.H + dH
        finite = _all_finite(A1, G1, H1)
        converged = finite & (_amax(dH) <= atol + rtol * _amax(H1)) & (_amax(A1) <= a_tol)
        return _Doubling(A=A1, G=G1, H=H1, converged=converged)

    init = _Doubling(A=A0, G=G0, H=H0, converged=jnp.array(False))
    return iterate(advance, init, done=lambda c: c.converged, max_steps=max_steps, fixed_steps=fixed_steps,
                   lanes=_DOUBLING_LANES)


def _remove_cross_term(A, B, Q, R, S):
    """``(A - B R^{-1} S, B R^{-1} B', Q - S' R^{-1} S, chol(R))`` from one Cholesky factorization of ``R``."""
    L = jnp.linalg.cholesky(_sym(R))
    Bt = jsl.solve_triangular(L, B.T, lower=True).T  # B L^{-T}
    St = jsl.solve_triangular(L, S, lower=True)  # L^{-1} S
    return A - matmul(Bt, St), _sym(matmul(Bt, Bt.T)), _sym(Q - matmul(St.T, St)), L


def _tolerances(rtol, atol, dtype):
    eps = jnp.finfo(dtype).eps
    rtol = 16 * eps if rtol is None else jnp.maximum(jnp.asarray(rtol, dtype), eps)
    return jnp.asarray(rtol, dtype), jnp.asarray(atol, dtype)


def _riccati_result(P, K, it: Iteration[_Doubling], residual, scale) -> RESULTS:
    """The status: a non-finite iterate, or a converged iteration whose Riccati residual is not
    small (``> sqrt(eps) * scale``), means no stabilizing solution; a finite iteration that ran out
    of steps, ``max_steps_reached``."""
    eps = jnp.finfo(P.dtype).eps
    finite = _all_finite(P, K, residual) & jnp.invert(it.nonfinite)
    small = residual <= jnp.sqrt(eps) * jnp.maximum(scale, jnp.finfo(P.dtype).tiny)
    return RESULTS.where(
        finite & jnp.invert(it.state.converged),
        RESULTS.max_steps_reached,
        RESULTS.where(finite & small, RESULTS.successful, RESULTS.no_stabilising_solution),
    )


# --------------------------------------------------------------------------------------------
# Implicit derivatives: Stein / Lyapunov solves by Smith's doubling.
# --------------------------------------------------------------------------------------------


class _Smith(eqx.Module):
    """Smith's doubling: ``M^(2^k)``, the partial sum ``X_k`` and whether it has settled."""

    Mk: Float[Array, "n n"]
    X: Float[Array, "n n"]
    done: Bool[Array, ""]


def _stein_doubling(M: Float[Array, "n n"], E: Float[Array, "n n"]) -> Float[Array, "n n"]:
    """``X = sum_j (M')^j E M^j``, the solution of ``X - M' X M = E`` (``rho(M) < 1``), by doubling.

    On the driver with its guard off: a non-finite partial sum ends the iteration and is returned
    as it is, so a derivative that does not exist comes out as NaN rather than as a finite guess.
    """
    eps = jnp.finfo(E.dtype).eps

    def body(c: _Smith) -> _Smith:
        inc = matmul(matmul(c.Mk.T, c.X), c.Mk)
        X = c.X + inc
        Mk = matmul(c.Mk, c.Mk)
        done = ((_amax(inc) <= eps * _amax(X)) & (_amax(Mk) <= jnp.sqrt(eps))) | jnp.invert(_all_finite(X, Mk))
        return _Smith(Mk=Mk, X=X, done=done)

    init = _Smith(Mk=M, X=E, done=jnp.array(False))
    return iterate(body, init, done=lambda c: c.done, max_steps=_STEIN_MAX_STEPS, finite=None).state.X


def _closed_loop_solve(Acl: Float[Array, "n n"], E: Float[Array, "n n"], continuous: bool) -> Float[Array, "n n"]:
    """Solve ``X - Acl' X Acl = E`` (discrete) or ``-(Acl' X + X Acl) = E`` (continuous) for ``X``.

    Wrapped in ``lax.custom_linear_solve`` (linear in ``E``, with the transposed solve), so it can
    be transposed for reverse-mode differentiation although the solve is a while loop.
    """
    n = Acl.shape[0]
    eye = jnp.eye(n, dtype=Acl.dtype)
    if continuous:
        # Cayley transform: with C = (Acl - g I)^{-1}, M = I + 2 g C,  Acl'X + X Acl = -E  <=>
        # X - M' X M = 2 g C' E C. The shift g is the RMS size of Acl's eigenvalues (a bound).
        g = jnp.sqrt(jnp.sum(Acl * Acl) / n)
        g = jnp.where(g > 0, g, 1)
        C = jnp.linalg.inv(Acl - g * eye)
        M = eye + 2 * g * C

        def matvec(X):
            return -(matmul(Acl.T, X) + matmul(X, Acl))

        def solve(_, b):
            return _stein_doubling(M, 2 * g * matmul(matmul(C.T, b), C))

        def transpose_solve(_, b):  # the adjoint operator -(Acl Y + Y Acl')
            return _stein_doubling(M.T, 2 * g * matmul(matmul(C, b), C.T))

    else:

        def matvec(X):
            return X - matmul(matmul(Acl.T, X), Acl)

        def solve(_, b):
            return _stein_doubling(Acl, b)

        def transpose_solve(_, b):  # the adjoint operator Y - Acl Y Acl'
            return _stein_doubling(Acl.T, b)

    return jax.lax.custom_linear_solve(matvec, E, solve, transpose_solve)


def _make_implicit(continuous: bool):
    """``f(P, A, B, Q, R, S) = P`` whose JVP is the implicit derivative of the Riccati solution.

    ``P`` must be the (stop-gradient-ed) solution for ``(A, B, Q, R, S)``; its own tangent is ignored.
    """

    @jax.custom_jvp
    def attach(P, A, B, Q, R, S):
        return P

    @attach.defjvp
    def attach_jvp(primals, tangents):
        P, A, B, Q, R, S = primals
        _, dA, dB, dQ, dR, dS = tangents
        # Through ``attach`` again, so that P carries its own (implicit) derivative when this rule
        # is differentiated in turn (Hessians); at first order this is just P.
        P = attach(P, A, B, Q, R, S)
        if continuous:
            K = jsl.cho_solve((jnp.linalg.cholesky(R), True), matmul(B.T, P) + S)
        else:
            BP = matmul(B.T, P)
            K = jsl.cho_solve((jnp.linalg.cholesky(_sym(R + matmul(BP, B))), True), matmul(BP, A) + S)
        Acl = A - matmul(B, K)
        dAcl = dA - matmul(dB, K)
        E = dQ + matmul(matmul(K.T, dR), K) - matmul(dS.T, K) - matmul(K.T, dS)
        if continuous:
            E = E + matmul(dAcl.T, P) + matmul(P, dAcl)
        else:
            E = E + matmul(matmul(dAcl.T, P), Acl) + matmul(matmul(Acl.T, P), dAcl)
        dP = _sym(_closed_loop_solve(Acl, _sym(E), continuous))
        return P, dP

    return attach


_implicit_discrete = _make_implicit(continuous=False)
_implicit_continuous = _make_implicit(continuous=True)


# --------------------------------------------------------------------------------------------
# DARE and CARE.
# --------------------------------------------------------------------------------------------


def _riccati_inputs(A, B, Q, R, S, max_steps):
    A = _as_float("A", A)
    if A.ndim != 2 or A.shape[0] == 0 or A.shape[0] != A.shape[1]:
        raise ValueError(f"A: expected a square matrix of shape (n, n) with n >= 1, got {_fmt(A.shape)}")
    n = A.shape[0]
    B = _as_float("B", B)
    if B.ndim != 2 or B.shape[-1] == 0:
        raise ValueError(f"B: expected shape (n, m) = ({n}, m) with m >= 1, got {_fmt(B.shape)}")
    sizes = dict(n=n, m=B.shape[1])
    _check_shape("B", B, ("n", "m"), sizes)
    Q = _as_float("Q", Q)
    _check_shape("Q", Q, ("n", "n"), sizes)
    R = _as_float("R", R)
    _check_shape("R", R, ("m", "m"), sizes)
    if S is not None:
        S = _as_float("S", S)
        _check_shape("S", S, ("m", "n"), sizes)
    _check_int("max_steps", max_steps, 1)
    dtype = _common_dtype(A, B, Q, R, S)
    S = jnp.zeros((sizes["m"], n), dtype) if S is None else S
    return tuple(x.astype(dtype) for x in (A, B, Q, R, S))


def dare(
    A: Float[ArrayLike, "n n"],
    B: Float[ArrayLike, "n m"],
    Q: Float[ArrayLike, "n n"],
    R: Float[ArrayLike, "m m"],
    *,
    S: Float[ArrayLike, "m n"] | None = None,
    max_steps: int = 50,
    rtol: float | None = None,
    atol: float = 0.0,
    fixed_steps: bool = False,
    throw: bool = False,
) -> RiccatiSolution:
    r"""Solve the discrete algebraic Riccati equation (infinite-horizon discrete LQR) by doubling.

    Finds the stabilizing ``P`` of ``P = A'PA - (A'PB + S')(R + B'PB)^{-1}(B'PA + S) + Q``, the
    value ``0.5 x'Px`` of ``min sum_t 0.5 (x_t'Q x_t + u_t'R u_t) + u_t'S x_t`` subject to
    ``x_{t+1} = A x_t + B u_t``, and the gain ``K = (R + B'PB)^{-1}(B'PA + S)`` of the optimal
    policy **``u = -K x``** (scipy's and python-control's convention; the finite-horizon
    :func:`lqr` uses ``u = K x + k`` instead). Same ``P`` as
    ``scipy.linalg.solve_discrete_are(A, B, Q, R, s=S.T)``.

    The structure-preserving doubling algorithm of the module docstring converges quadratically;
    the default ``max_steps = 50`` doublings stand for ``2^50`` Riccati-recursion steps, so
    running out of steps means a closed-loop eigenvalue (numerically) on the unit circle. It needs
    ``R`` positive definite, ``(A, B)`` stabilizable and ``(A - B R^{-1} S, Q - S'R^{-1}S)``
    detectable (no unstable mode that the cost does not see); it reports
    ``RESULTS.no_stabilising_solution`` otherwise (scipy's QZ method can still return the
    stabilizing solution of an undetectable problem; this solver does not).

    Differentiable (``jax.grad``, ``jax.jvp``) with respect to ``A, B, Q, R, S`` by implicit
    differentiation (module docstring); the iteration is not unrolled. Only the symmetric parts
    of ``Q`` and ``R`` are used.

    Args:
        A: ``[n, n]`` state-transition matrix.
        B: ``[n, m]`` control matrix.
        Q: ``[n, n]`` state cost (symmetric positive semi-definite for the usual guarantees).
        R: ``[m, m]`` control cost, symmetric positive definite.
        S: optional ``[m, n]`` cross term ``u'S x`` (scipy's ``s`` is ``S.T``). Default zero.
        max_steps: the most doubling iterations (static int >= 1).
        rtol: relative tolerance on the last increment of ``P`` (default ``16 eps`` of the dtype;
            the increments vanish quadratically, so machine precision costs one more iteration
            at most). A float is static under jit; pass an array to sweep it under ``vmap``.
        atol: absolute tolerance on the last increment of ``P``.
        fixed_steps: if true, run exactly ``max_steps`` iterations in a ``lax.scan``, freezing
            each problem once it has converged (same result as the adaptive ``lax.while_loop``);
            for large batches, where a while loop runs until its slowest element anyway. Use a
            small ``max_steps``: about 15 covers closed-loop spectral radii up to 0.999 and 20 up
            to 0.9999 (the error after ``k`` steps is ``~rho^(2^(k+1))``).
        throw: if true, raise unless the solve succeeds (under ``vmap``: if any element fails).

    Returns:
        A :class:`RiccatiSolution` ``(P [n, n], K [m, n], result, stats)``.

    Raises:
        ValueError: an argument has the wrong shape or is complex, or ``max_steps`` is not a
            positive int. Raised in Python, before anything is computed.
        equinox.EquinoxRuntimeError: ``throw=True`` and the solve failed.
    """
    A, B, Q, R, S = _riccati_inputs(A, B, Q, R, S, max_steps)
    return _dare(A, B, Q, R, S, rtol, atol, max_steps, fixed_steps, throw)


@eqx.filter_jit
def _dare(A, B, Q, R, S, rtol, atol, max_steps, fixed_steps, throw) -> RiccatiSolution:
    Q, R = _sym(Q), _sym(R)
    rtol, atol = _tolerances(rtol, atol, A.dtype)
    sg = jax.lax.stop_gradient
    At, G, Ht, _ = _remove_cross_term(sg(A), sg(B), sg(Q), sg(R), sg(S))
    it = _sda(At, G, Ht, rtol, atol, max_steps, fixed_steps)
    P = _implicit_discrete(sg(it.state.H), A, B, Q, R, S)
    BP = matmul(B.T, P)
    N = matmul(BP, A) + S  # B'PA + S
    K = jsl.cho_solve((jnp.linalg.cholesky(_sym(R + matmul(BP, B))), True), N)
    APA = matmul(matmul(A.T, P), A)
    F = APA - P - matmul(N.T, K) + Q
    residual = _amax(F)
    result = _riccati_result(P, K, it, residual, _amax(APA) + _amax(P) + _amax(Q))
    if throw:
        P = result.error_if(P, result != RESULTS.successful)
    stats = dict(num_steps=it.num_steps, residual=residual)
    return RiccatiSolution(P=P, K=K, result=result, stats=stats)


def care(
    A: Float[ArrayLike, "n n"],
    B: Float[ArrayLike, "n m"],
    Q: Float[ArrayLike, "n n"],
    R: Float[ArrayLike, "m m"],
    *,
    S: Float[ArrayLike, "m n"] | None = None,
    gamma: float | None = None,
    max_steps: int = 50,
    rtol: float | None = None,
    atol: float = 0.0,
    fixed_steps: bool = False,
    throw: bool = False,
) -> RiccatiSolution:
    r"""Solve the continuous algebraic Riccati equation (infinite-horizon continuous LQR).

    Finds the stabilizing ``P`` of ``A'P + PA - (PB + S') R^{-1} (B'P + S) + Q = 0``, the value
    ``0.5 x'Px`` of ``min int 0.5 (x'Qx + u'Ru) + u'S x dt`` subject to ``xdot = A x + B u``, and
    the gain ``K = R^{-1}(B'P + S)`` of the optimal policy **``u = -K x``**. Same ``P`` as
    ``scipy.linalg.solve_continuous_are(A, B, Q, R, s=S.T)``.

    A Cayley transform with shift ``gamma`` turns the equation into a discrete one with the same
    stabilizing solution (module docstring), solved by the doubling iteration of :func:`dare`. The
    closed-loop eigenvalues ``lambda`` become ``(lambda + gamma) / (lambda - gamma)``; the
    iteration is fastest when ``gamma`` is near their magnitudes. The default is the RMS
    eigenvalue bound ``|Ham|_F / sqrt(2 n)`` of the Hamiltonian matrix. ``gamma`` must not be an
    eigenvalue of ``A - B R^{-1} S`` (the result is then ``no_stabilising_solution``). Assumptions,
    statuses and differentiability as for :func:`dare` (the implicit derivative solves the
    closed-loop Lyapunov equation).

    Args:
        A: ``[n, n]`` system matrix.
        B: ``[n, m]`` input matrix.
        Q: ``[n, n]`` state cost.
        R: ``[m, m]`` control cost, symmetric positive definite.
        S: optional ``[m, n]`` cross term ``u'S x`` (scipy's ``s`` is ``S.T``). Default zero.
        gamma: optional positive Cayley shift (a float, or an array to sweep under ``vmap``).
        max_steps: the most doubling iterations (static int >= 1).
        rtol: relative tolerance on the last increment of ``P`` (default ``16 eps``).
        atol: absolute tolerance on the last increment of ``P``.
        fixed_steps: as for :func:`dare`.
        throw: if true, raise unless the solve succeeds (under ``vmap``: if any element fails).

    Returns:
        A :class:`RiccatiSolution` ``(P [n, n], K [m, n], result, stats)``.

    Raises:
        ValueError: an argument has the wrong shape or is complex, ``max_steps`` is not a
            positive int or ``gamma`` is not positive. Raised in Python, before anything is
            computed.
        equinox.EquinoxRuntimeError: ``throw=True`` and the solve failed.
    """
    A, B, Q, R, S = _riccati_inputs(A, B, Q, R, S, max_steps)
    if gamma is not None and not isinstance(gamma, jax.core.Tracer):
        g = np.asarray(gamma)
        if g.shape != () or not np.isfinite(g) or g <= 0:
            raise ValueError(f"gamma: expected a positive scalar, got {gamma!r}")
    return _care(A, B, Q, R, S, gamma, rtol, atol, max_steps, fixed_steps, throw)


@eqx.filter_jit
def _care(A, B, Q, R, S, gamma, rtol, atol, max_steps, fixed_steps, throw) -> RiccatiSolution:
    n = A.shape[0]
    dtype = A.dtype
    eye = jnp.eye(n, dtype=dtype)
    Q, R = _sym(Q), _sym(R)
    rtol, atol = _tolerances(rtol, atol, dtype)
    sg = jax.lax.stop_gradient
    At, G, Ht, _ = _remove_cross_term(sg(A), sg(B), sg(Q), sg(R), sg(S))
    if gamma is None:
        g = jnp.sqrt((2 * jnp.sum(At * At) + jnp.sum(G * G) + jnp.sum(Ht * Ht)) / (2 * n))
        g = jnp.where(g > 0, g, 1)
    else:
        g = jnp.asarray(gamma, dtype)
    Ag = At - g * eye
    AgiT_H = jnp.linalg.solve(Ag.T, Ht)  # Ag^{-T} H
    W = Ag + matmul(G, AgiT_H)
    Agi_G = jnp.linalg.solve(Ag, G)  # Ag^{-1} G;  G Ag^{-T} = (Ag^{-1} G)'
    A_hat = eye + 2 * g * jnp.linalg.solve(W, eye)
    G_hat = _sym(2 * g * jnp.linalg.solve(W, Agi_G.T))
    H_hat = _sym(2 * g * jnp.linalg.solve(W.T, AgiT_H.T))  # H Ag^{-1} = (Ag^{-T} H)'
    it = _sda(A_hat, G_hat, H_hat, rtol, atol, max_steps, fixed_steps)
    P = _implicit_continuous(sg(it.state.H), A, B, Q, R, S)
    N = matmul(B.T, P) + S
    K = jsl.cho_solve((jnp.linalg.cholesky(R), True), N)
    AP = matmul(A.T, P)
    F = AP + AP.T - matmul(N.T, K) + Q
    residual = _amax(F)
    result = _riccati_result(P, K, it, residual, 2 * _amax(AP) + _amax(matmul(N.T, K)) + _amax(Q))
    if throw:
        P = result.error_if(P, result != RESULTS.successful)
    stats = dict(num_steps=it.num_steps, residual=residual)
    return RiccatiSolution(P=P, K=K, result=result, stats=stats)
