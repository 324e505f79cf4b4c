"""A batched ``lax.while_loop`` that costs its mean trip count, not its maximum (lane compaction).

Under ``jax.vmap`` a ``lax.while_loop`` steps every element until the slowest one of the batch has
finished: a batch of IK problems that take 15 iterations on average and 33 at most costs 33 steps
of the whole batch. :func:`while_loop` instead runs the batch through a fixed number of *lanes*:
each iteration steps every lane once; a lane whose problem has finished writes that problem's
final state to its place in the output and takes the next waiting problem. A batch of ``N``
problems then costs about ``N * mean + lanes * max`` lane-steps instead of ``N * max``, and the
lanes' working set is a fraction of the batch's (it stays in cache).

The one-instance call is ``lax.while_loop`` itself, and every problem takes exactly the steps it
would take alone, from the same initial state with the same data, so the batched result equals
``jax.vmap(lax.while_loop)`` element by element up to round-off of the vector width (tests check
it). Results come back in input order. The routing goes through
:func:`jax.custom_batching.custom_vmap`; nested vmap works (the outer axes are an ordinary vmap
of the compacted loop) and so does forward mode. There is no reverse-mode rule, as there is none
for ``lax.while_loop``. On other backends than the CPU, where one wide program is what the
hardware wants, a batched call is the plain vmapped loop.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["LANES", "hoist_closure", "lane_map", "repeat_while", "while_loop"]

LANES = 128
"""Lanes of a compacted loop (a batch of at most this many runs as one plain vmapped loop).
Fewer lanes waste less on the last problems (``lanes * max`` steps) but pay the per-op
overhead of XLA:CPU (about a microsecond an op) on more iterations."""


def hoist_closure(fun: Callable, *example_args) -> tuple[Callable, list]:
    """``(converted, consts)``: ``converted(*args, *consts) == fun(*args)`` with every tracer that
    ``fun`` closes over (batched or not, of any dtype) hoisted into ``consts``.

    ``jax.closure_convert`` hoists only values that may carry a tangent; a batched integer array
    in the closure would stay there, and ``custom_vmap`` refuses batched closed-over values.
    """
    closed, out_shape = jax.make_jaxpr(fun, return_shape=True)(*example_args)
    jaxpr, consts = closed.jaxpr, closed.consts
    hoisted = [i for i, c in enumerate(consts) if isinstance(c, jax.core.Tracer)]
    out_tree = jax.tree.structure(out_shape)

    def converted(*args_and_consts):
        args, extra = args_and_consts[: len(example_args)], args_and_consts[len(example_args):]
        cs = list(consts)
        for i, c in zip(hoisted, extra):
            cs[i] = c
        return jax.tree.unflatten(out_tree, jax.core.eval_jaxpr(jaxpr, cs, *jax.tree.leaves(args)))

    return converted, [consts[i] for i in hoisted]


def _check_count(name: str, value) -> None:
    """A static count (lanes, a width, passes) must be an int >= 1: named here, not a division by zero inside."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name}: expected an int >= 1, got {value!r}")


def _take(tree, idx):
    """Rows ``idx`` of every leaf (indices clipped: an idle lane reads a valid row)."""
    return jax.tree.map(lambda x: jnp.take(x, idx, axis=0, mode="clip"), tree)


def _select(pred, a, b):
    return jax.tree.map(lambda x, y: jnp.where(pred.reshape(pred.shape + (1,) * (x.ndim - 1)), x, y), a, b)


def while_loop(cond: Callable[[Any], Any], body: Callable[[Any], Any], init: Any, *, lanes: int = LANES) -> Any:
    """``lax.while_loop(cond, body, init)``, whose batched calls are compacted onto ``lanes`` lanes.

    ``cond`` and ``body`` may close over batched values (they are hoisted into arguments).
    """
    _check_count("lanes", lanes)
    cond_of, cond_consts = hoist_closure(cond, init)
    body_of, body_consts = hoist_closure(body, init)
    nc = len(cond_consts)

    def loop(x0, *consts):
        cc, bc = consts[:nc], consts[nc:]
        return jax.lax.while_loop(lambda x: cond_of(x, *cc), lambda x: body_of(x, *bc), x0)

    routed = jax.custom_batching.custom_vmap(loop)

    @routed.def_vmap
    def _rule(axis_size: int, in_batched, x0, *consts):
        if not any(jax.tree.leaves(in_batched)):  # forward mode may ask for this: one loop
            out = loop(x0, *consts)
            return out, jax.tree.map(lambda _: False, out)
        if axis_size <= lanes or jax.default_backend() != "cpu":
            out = jax.vmap(loop, in_axes=(_axes(in_batched[0]), *map(_axes, in_batched[1:])))(x0, *consts)
            return out, jax.tree.map(lambda _: True, out)
        x0 = _broadcast(x0, in_batched[0], axis_size)
        return _compacted(axis_size, lanes, x0, consts, in_batched[1:], cond_of, body_of, nc), \
            jax.tree.map(lambda _: True, x0)

    return routed(init, *cond_consts, *body_consts)


def lane_map(fun: Callable[..., Any], *args: Any, lanes: int = LANES, chunks: bool = True,
             reverse: bool = False) -> Any:
    """``fun(*args)``, whose batched calls run ``lanes`` problems at a time (a ``lax.map`` over chunks).

    Beside a compacted :func:`while_loop`, the work before and after the loop (an initial
    linearization, a final evaluation) then has the loop body's shapes, ``[lanes, ...]``: XLA:CPU
    compiles one kernel per distinct fused computation and shape, so those kernels are shared with
    the body's instead of being built again at the batch's size (batched IK at 1024: 441 kernel
    objects instead of 535, about 1-1.5 s less compile in A/B runs). The values are those of
    ``jax.vmap(fun)``; small batches (at most ``lanes``) and other backends than the CPU take the
    plain vmap. ``chunks=False`` (static) is ``fun(*args)`` itself: beside a loop that is not
    compacted (a ``fixed_steps`` scan runs at the batch's shapes, which the plain call has).

    Differentiated, it is ``fun`` itself, plainly vmapped: by default through a custom JVP (forward
    and reverse mode); ``reverse=True`` (static) through a custom VJP instead, for a ``fun`` that has
    only a reverse-mode derivative (a checkpointed while loop): its forward pass is ``jax.vjp`` of
    ``fun``, whose residuals the backward pass takes (``fun`` runs once, not in chunks; it used to run
    in chunks and again in the backward pass), and forward mode is unavailable.
    """
    if not chunks:
        return fun(*args)
    _check_count("lanes", lanes)
    fun_of, consts = hoist_closure(fun, *args)
    routed = jax.custom_batching.custom_vmap(lambda *a: fun_of(*a))

    @routed.def_vmap
    def _rule(axis_size: int, in_batched, *a):
        axes = tuple(map(_axes, in_batched))
        if not any(jax.tree.leaves(in_batched)):
            out = fun_of(*a)
            return out, jax.tree.map(lambda _: False, out)
        if axis_size <= lanes or jax.default_backend() != "cpu":
            out = jax.vmap(fun_of, in_axes=axes)(*a)
            return out, jax.tree.map(lambda _: True, out)
        k = -(-axis_size // lanes)
        leaves, tree = jax.tree.flatten(a)
        flags = jax.tree.leaves(in_batched)

        def chunked(x):  # [n, ...] -> [k, lanes, ...], padded with copies of the last row
            pad = k * lanes - axis_size
            x = jnp.concatenate([x, jnp.broadcast_to(x[-1:], (pad, *x.shape[1:]))]) if pad else x
            return x.reshape(k, lanes, *x.shape[1:])

        def one_chunk(rows):  # the batched leaves' rows of one chunk; the others shared
            it = iter(rows)
            full = jax.tree.unflatten(tree, [next(it) if f else x for x, f in zip(leaves, flags)])
            return jax.vmap(fun_of, in_axes=axes)(*full)

        out = jax.lax.map(one_chunk, [chunked(x) for x, f in zip(leaves, flags) if f])
        out = jax.tree.map(lambda y: y.reshape(k * lanes, *y.shape[2:])[:axis_size], out)
        return out, jax.tree.map(lambda _: True, out)

    # custom_vmap has no derivative rule: differentiated, it is fun itself (plainly vmapped)
    if reverse:
        reversible = jax.custom_vjp(lambda *a: routed(*a))

        def forward(*a):  # the plain call's own forward pass, whose residuals the backward pass uses
            return jax.vjp(fun_of, *a)

        reversible.defvjp(forward, lambda pullback, ct: pullback(ct))
        return reversible(*args, *consts)
    differentiable = eqx.filter_custom_jvp(lambda *a: routed(*a))

    @differentiable.def_jvp
    def _jvp(primals, tangents):
        return eqx.filter_jvp(fun_of, primals, tangents)

    return differentiable(*args, *consts)


def repeat_while(body: Callable[[Any, Any], Any], needed: Callable[[Any], Any], init: Any, *, times: int,
                 lanes: int = LANES, width: int = 256) -> Any:
    """``x = body(0, init)``, then ``x = body(i, x)`` for ``i = 1, 2, ...`` while ``i < times`` and
    ``needed(x)``: a few passes of which most problems need only the first.

    One instance is a ``lax.fori_loop`` of ``times`` passes, each a ``lax.cond`` (a pass that is not
    needed is skipped, in forward and reverse mode alike: the derivative is that of the passes run).
    Under ``vmap`` on the CPU, with more problems than ``lanes``, the first pass runs on the whole
    batch, ``width`` problems at a time (:func:`lane_map`), and the later ones through the lanes of
    :func:`while_loop`, which only the problems that need them enter: a problem leaves its lane after
    its last needed pass, so a batch costs one wide pass and about as many narrow ones as its problems
    need, where the vmapped ``lax.cond`` would run every pass on every problem (its predicate is
    batched). ``body`` then appears twice in the program (once at each width; once otherwise). Each
    problem's value is the one-instance value (up to round-off of the vector width). ``body`` and
    ``needed`` may close over batched values; ``i`` is a traced integer.
    """

    for name, count in (("times", times), ("lanes", lanes), ("width", width)):
        _check_count(name, count)
    body_of, body_consts = hoist_closure(body, jnp.asarray(0), init)
    needed_of, needed_consts = hoist_closure(needed, init)
    nb = len(body_consts)

    def plain(x0, *consts):
        bc, nc = consts[:nb], consts[nb:]

        def step(i, c):
            x, go = c
            go = (i == 0) | (go & needed_of(x, *nc))
            return jax.lax.cond(go, lambda x: body_of(i, x, *bc), lambda x: x, x), go

        return jax.lax.fori_loop(0, times, step, (x0, jnp.asarray(True)))[0]

    def compacted(axis_size, in_batched, x0, *consts):
        # the first pass on the whole batch, width problems at a time; the later ones through the lanes, which
        # only the problems that need them enter (their order puts them first)
        axes = tuple(map(_axes, in_batched))
        bc, nc = consts[:nb], consts[nb:]

        def first(x, *c):
            return lane_map(lambda x, *c: body_of(jnp.asarray(0), x, *c), x, *c, lanes=width)

        x1 = jax.vmap(first, in_axes=axes[:1 + nb])(x0, *bc)
        if times == 1:
            return x1
        need = jax.vmap(needed_of, in_axes=(0, *axes[1 + nb:]))(x1, *nc)
        order = jnp.zeros(axis_size, int).at[jnp.where(need, jnp.cumsum(need) - 1, axis_size)].set(
            jnp.arange(axis_size), mode="drop")
        return _compacted(axis_size, lanes, (jnp.ones(axis_size, int), x1), nc + bc,
                          in_batched[1 + nb:] + in_batched[1:1 + nb],  # the needed's constants first, as nc + bc
                          lambda c, *k: (c[0] < times) & needed_of(c[1], *k),
                          lambda c, *k: (c[0] + 1, body_of(c[0], c[1], *k)), len(nc),
                          order=order, count=jnp.sum(need))[1]

    routed = jax.custom_batching.custom_vmap(plain)

    @routed.def_vmap
    def _rule(axis_size: int, in_batched, x0, *cs):
        if not any(jax.tree.leaves(in_batched)):  # as in while_loop's rule: one instance
            out = plain(x0, *cs)
            return out, jax.tree.map(lambda _: False, out)
        if axis_size <= lanes or jax.default_backend() != "cpu":
            out = jax.vmap(plain, in_axes=tuple(map(_axes, in_batched)))(x0, *cs)
        else:
            x0 = _broadcast(x0, in_batched[0], axis_size)
            out = compacted(axis_size, (jax.tree.map(lambda _: True, x0), *in_batched[1:]), x0, *cs)
        return out, jax.tree.map(lambda _: True, out)

    differentiable = eqx.filter_custom_jvp(lambda *a: routed(*a))

    @differentiable.def_jvp
    def _jvp(primals, tangents):
        return eqx.filter_jvp(plain, primals, tangents)

    return differentiable(init, *body_consts, *needed_consts)


def _broadcast(tree, batched_tree, n):
    """``tree`` with its unbatched leaves broadcast to a leading axis of ``n`` (a loop state is batched whole)."""
    return jax.tree.map(lambda x, b: x if b else jnp.broadcast_to(x, (n, *jnp.shape(x))), tree, batched_tree)


def _axes(batched_tree):
    return jax.tree.map(lambda b: 0 if b else None, batched_tree)


class _Packing:
    """The leaves of a batched pytree (leading axis: the problems) packed into one ``[rows, width]``
    array per dtype, and back. The compacted loop gathers, selects and scatters whole lane states:
    on packed states that is a few ops instead of a few per leaf (XLA:CPU compiles every op of
    the loop into a kernel of its own, so each leaf cost compile time)."""

    def __init__(self, tree):
        leaves, self.treedef = jax.tree.flatten(tree)
        self.dtypes = sorted({jnp.result_type(x) for x in leaves}, key=str)
        self.slots, width = [], {d: 0 for d in self.dtypes}
        for x in leaves:
            d, size = jnp.result_type(x), int(np.prod(jnp.shape(x)[1:], dtype=np.int64))
            self.slots.append((d, width[d], size, jnp.shape(x)[1:]))
            width[d] += size

    def pack(self, tree) -> tuple:
        leaves = jax.tree.leaves(tree)
        rows = jnp.shape(leaves[0])[0] if leaves else 0
        groups = {d: [] for d in self.dtypes}
        for x, (d, _, size, _) in zip(leaves, self.slots):
            groups[d].append(jnp.reshape(x, (rows, size)))
        return tuple(g[0] if len(g) == 1 else jnp.concatenate(g, axis=1) for g in groups.values())

    def unpack(self, packed) -> Any:
        by = dict(zip(self.dtypes, packed))
        leaves = [jnp.reshape(by[d][..., o:o + size], by[d].shape[:-1] + shape) for d, o, size, shape in self.slots]
        return jax.tree.unflatten(self.treedef, leaves)


def _compacted(n, lanes, x0, consts, flags, cond_of, body_of, nc, order=None, count=None):
    """The compacted loop over ``n`` problems: ``x0`` batched (all ``n``), ``consts[i]`` batched where
    ``flags[i]`` says so (their rows are gathered per lane), the others shared. With ``order [n]`` and
    ``count`` (traced), only the problems ``order[:count]`` enter the lanes, in that order; the others'
    results are their ``x0``."""
    axes = tuple(_axes(f) for f in flags)
    batched = [i for i, f in enumerate(flags) if any(jax.tree.leaves(f))]
    xs, cs = _Packing(x0), _Packing(tuple(consts[i] for i in batched))
    X0, C = xs.pack(x0), cs.pack(tuple(consts[i] for i in batched))

    def full(lc):  # every constant, the batched ones replaced by their lane rows
        out = list(consts)
        for i, c in zip(batched, cs.unpack(lc)):
            out[i] = c
        return out

    def running(X, lc):  # [lanes] bool: the lane's problem is not finished
        return jax.vmap(lambda x, *c: cond_of(x, *c[:nc]), in_axes=(0, *axes))(xs.unpack(X), *full(lc))

    def step(X, lc):
        return xs.pack(jax.vmap(lambda x, *c: body_of(x, *c[nc:]), in_axes=(0, *axes))(xs.unpack(X), *full(lc)))

    if order is None:
        order, count = jnp.arange(n), jnp.asarray(n)

    def rows(pos):  # the problems at these places of the order (an idle lane's place n reads a valid row)
        return jnp.take(order, pos, mode="clip")

    idx0 = jnp.arange(lanes)
    idx0 = jnp.where(idx0 < count, idx0, n)
    carry0 = (idx0, _take(X0, rows(idx0)), _take(C, rows(idx0)), jnp.minimum(count, lanes), X0)

    def outer_cond(c):
        return jnp.any(c[0] < n)

    def outer_body(c):
        idx, X, lc, nxt, out = c
        valid = idx < n
        finished = valid & jnp.invert(running(X, lc))
        # finished lanes write their problem back in place (idle and running lanes write nowhere)
        out = jax.tree.map(lambda o, v: o.at[jnp.where(finished, rows(idx), n)].set(v, mode="drop"), out, X)
        # ... and take the next waiting problems, in order
        new = nxt + jnp.cumsum(finished) - 1
        idx = jnp.where(finished, jnp.where(new < count, new, n), idx)
        nxt = nxt + jnp.sum(finished)
        load = finished & (idx < n)
        X = _select(load, _take(X0, rows(idx)), X)
        lc = _select(load, _take(C, rows(idx)), lc)
        active = (idx < n) & running(X, lc)
        X = _select(active, step(X, lc), X)
        return idx, X, lc, nxt, out

    return xs.unpack(jax.lax.while_loop(outer_cond, outer_body, carry0)[-1])
