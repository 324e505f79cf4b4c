"""The least-squares problem: the residual, its Jacobian and the box, as the solvers see them."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, PyTree

from ._linalg import matmul

ResidualFn = Callable[[Float[Array, " n"], Any], Float[Array, " m"]]
JacobianFn = Callable[[Float[Array, " n"], Any], Float[Array, "m n"]]


class _Problem(eqx.Module):
    """``fn``/``jac`` and the box of one solve (built inside the jitted function)."""

    fn: ResidualFn = eqx.field(static=True)
    jac: JacobianFn | bool | None = eqx.field(static=True)  # True: fn returns (r, J)
    lower: Float[Array, " n"] | None
    upper: Float[Array, " n"] | None
    m: int = eqx.field(static=True)
    stop: Callable | None = eqx.field(static=True, default=None)

    @property
    def bounded(self) -> bool:
        return self.lower is not None

    def residual(self, y: Float[Array, " n"], args: PyTree) -> Float[Array, " m"]:
        if self.jac is True:  # the Jacobian is dead code here: XLA removes it
            return jnp.asarray(self.fn(y, args)[0]).astype(y.dtype)
        return jnp.asarray(self.fn(y, args)).astype(y.dtype)

    def linearize(self, y: Float[Array, " n"], args: PyTree) -> tuple[Float[Array, " m"], Float[Array, "m n"]]:
        """``(r(y), J(y))``: one call of ``fn`` when it returns both (``jac=True``), the user's
        ``jac`` if given, else forward (``m >= n``) or reverse mode."""
        if self.jac is True:
            r, J = self.fn(y, args)
            return jnp.asarray(r).astype(y.dtype), jnp.asarray(J).astype(y.dtype)
        if self.jac is not None:
            return self.residual(y, args), jnp.asarray(self.jac(y, args)).astype(y.dtype)

        def f(z):
            rz = self.residual(z, args)
            return rz, rz

        jacobian = jax.jacfwd if self.m >= y.shape[0] else jax.jacrev
        J, r = jacobian(f, has_aux=True)(y)
        return r, J

    def project(self, y: Float[Array, " n"]) -> Float[Array, " n"]:
        return jnp.clip(y, self.lower, self.upper) if self.bounded else y

    def free(self, y: Float[Array, " n"], g: Float[Array, " n"]) -> Bool[Array, " n"] | None:
        """Variables not frozen: frozen = at a bound with the gradient pushing outwards."""
        if not self.bounded:
            return None
        frozen = ((y <= self.lower) & (g > 0)) | ((y >= self.upper) & (g < 0))
        return jnp.invert(frozen)

    def custom_jvp_residual(self) -> ResidualFn:
        """``fn`` for the backends: with a ``jax.custom_jvp`` that uses ``jac`` when one is given.

        Tangents with respect to ``y`` go through ``J(y) @ t_y``; tangents with respect to array
        leaves of ``args`` (only present when the caller differentiates through the solve) go
        through ``jax.jvp`` of ``fn``. Non-array leaves of ``args`` are closed over.
        """
        fn, jac = self.fn, self.jac
        if jac is None:
            return fn
        if jac is True:
            fused = fn
            fn = lambda y, args: fused(y, args)[0]  # noqa: E731
            jac = lambda y, args: fused(y, args)[1]  # noqa: E731

        def wrapped(y, args):
            dyn, static = eqx.partition(args, eqx.is_array)

            @jax.custom_jvp
            def res(y_, dyn_):
                return fn(y_, eqx.combine(dyn_, static))

            def res_jvp(primals, tangents):
                y_, dyn_ = primals
                t_y, t_dyn = tangents
                a = eqx.combine(dyn_, static)
                r = jnp.asarray(fn(y_, a))
                out = jnp.zeros_like(r)
                if not isinstance(t_y, jax.custom_derivatives.SymbolicZero):
                    out = out + matmul(jnp.asarray(jac(y_, a)).astype(r.dtype), t_y.astype(r.dtype))
                t_leaves = jax.tree.leaves(t_dyn, is_leaf=lambda x: isinstance(x, jax.custom_derivatives.SymbolicZero))
                if any(not isinstance(t, jax.custom_derivatives.SymbolicZero) for t in t_leaves):
                    t_dyn = jax.tree.map(
                        lambda t, p: jnp.zeros_like(p) if isinstance(t, jax.custom_derivatives.SymbolicZero) else t,
                        t_dyn,
                        dyn_,
                        is_leaf=lambda x: isinstance(x, jax.custom_derivatives.SymbolicZero),
                    )
                    _, r_dot = jax.jvp(lambda d: fn(y_, eqx.combine(d, static)), (dyn_,), (t_dyn,))
                    out = out + r_dot
                return r, out

            res.defjvp(res_jvp, symbolic_zeros=True)
            return res(y, dyn)

        return wrapped

