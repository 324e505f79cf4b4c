r"""Articulated rigid-body simulation: the model, one time step, and export to MuJoCo's MJCF.

:class:`PhysicsModel` holds the bodies (:class:`~jaxanim.rigid.RigidBodies`), the joints
(:class:`~jaxanim.joints.Joints`) and the constraint parameters; the state is a
:class:`~jaxanim.rigid.BodyState`. :func:`step` advances it by one step of the course notes'
eq. 6.28 (maximal coordinates, velocity-level constraints):

1. free velocities from the loads, ``v* = v + h (f/m + g)``, ``omega* = omega + h I_n^{-1} tau``
   (joint torques ``tau_j`` act as ``+tau_j`` on the child and ``-tau_j`` on the parent, eq. 7.1);
2. the joint impulses ``lambda`` from ``(J M^{-1} J' + cfm I) lambda = -(erp / h) g - J [v*; omega*]``
   (eq. 6.20 with ERP and CFM), ``[v; omega] = [v*; omega*] + M^{-1} J' lambda``, ``M = diag(m I,
   I_n)``, ``J`` and ``g`` at step ``n`` (:func:`~jaxanim.joints.joint_rows`);
3. ``x_{n+1} = x_n + h v``, ``q_{n+1} = normalize(q_n + (h/2) [0, omega] q_n)``, and the angular
   velocity re-expressed at ``q_{n+1}`` with the angular momentum ``I_n omega`` of each body
   (the gyroscopic term in momentum form, as :func:`~jaxanim.rigid.step_free`).

**Solver for step 2**: exact and ``O(bodies)``. The joints must form a forest (each body the child
of at most one joint, no cycles). Bodies are eliminated from the leaves to the roots: each child's
articulated ``6 x 6`` inertia is folded into its parent through its joint's small system
(``k x k``, ``k`` = the joint's rows), then velocities and impulses are back-substituted from the
roots (:func:`~jaxanim.physics._tree_solve._tree_solve`; the block elimination of the augmented system ``[[M, -J'], [J, cfm]]``
in the order of its tree, Baraff 1996, without fill-in). Bodies at the same depth are processed
together, so a 21-body character takes as many passes as its tree is deep. ``cfm`` keeps each
joint's system positive definite. Stable-PD rows (``spd``) are soft rows of their joint's system;
the root servo's soft rows are folded into its body's inertia.

**One-sided rows** (complementarity contact, :mod:`jaxanim.contact`, and joint limits,
:func:`~jaxanim.joints.limit_rows`): the same solve gives each row's effect ``Y = H^{-1} J_u'`` on
the velocities with the joints held exactly, hence their Delassus matrix ``J_u Y`` (``U x U``), on
which projected Gauss-Seidel runs a fixed number of sweeps (``ground.iterations``). Penalty
contact instead adds forces to the loads of step 1.

Where the code is: the model here (:class:`PhysicsModel`, :func:`make_model`), the inputs of a
step in :mod:`._control` (:class:`~jaxanim.physics.Control`), the tree solve in :mod:`._tree_solve`,
one step in :mod:`._step`, rollouts in :mod:`._rollout`, the MJCF export in :mod:`._mjcf`.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._errors import JaxanimError
from ._bodies import BodyState, RigidBodies, _check_model
from ._contact import Ground, make_ground
from ._joints import Joints, joint_rows
from ._tree_solve import _plan

__all__ = ["PhysicsModel", "joint_error", "make_model"]

class PhysicsModel(eqx.Module):
    """Bodies, joints and constraint parameters (the constant part of a simulation).

    Attributes:
        bodies: the rigid bodies.
        joints: the joints (may be empty).
        erp: the error-reduction parameter in ``[0, 1]``: the fraction of each joint's position
            error removed per step (default 0.5: the first-order rotation update leaves an
            ``O(h^2 omega^2 r)`` anchor error per step, and the steady drift is that over ``erp``;
            a double pendulum of 0.5 m capsules drifts < 5e-5 m at 600 Hz).
        cfm: constraint-force mixing, added to the diagonal of ``J M^{-1} J'``.
        ground: the ground plane and contact model (:class:`~jaxanim.contact.Ground`; model
            ``"none"`` for no contact).
        scan_levels: solve the joint tree's depth levels in a ``lax.scan`` (static; see
            :func:`make_model`).
    """

    bodies: RigidBodies
    joints: Joints
    erp: Float[Array, ""]
    cfm: Float[Array, ""]
    ground: Ground
    scan_levels: bool = eqx.field(static=True, default=False)


def make_model(
    bodies: RigidBodies, joints: Joints | None = None, *, ground: Ground | None = None, erp: float = 0.5,
    cfm: float = 1e-10, scan_levels: bool = False,
) -> PhysicsModel:
    """A :class:`PhysicsModel`; ``erp`` in ``[0, 1]``, ``cfm >= 0``; no joints and no ground by
    default (:func:`~jaxanim.contact.make_ground` for one).

    ``scan_levels`` trades run time for compile time: the joint tree's depth levels are solved in
    a ``lax.scan`` instead of being written out one by one. Same results to round-off (XLA may round a small
    matrix-vector product differently in the two programs: 3e-13 after 60 steps in the tests); on the CMU
    character (7 levels) an unbatched rollout compiles in 2.5 s instead of 4.2 s, and a step at
    batch 1024 takes ~1.4x as long (dynamic gathers and scatters instead of static slices).

    Raises:
        JaxanimError: ``erp`` / ``cfm`` out of range, joints naming bodies out of range, or joints
            forming a cycle (the solver needs a forest).
    """
    _check_model(bodies)
    if not 0 <= erp <= 1:
        raise JaxanimError(f"erp: expected a value in [0, 1], got {erp!r}")
    if not cfm >= 0:
        raise JaxanimError(f"cfm: expected >= 0, got {cfm!r}")
    if joints is None:
        z = np.zeros((0, 3))
        joints = Joints(names=(), types=(), parent=(), child=(), anchor_parent=jnp.asarray(z), anchor_child=jnp.asarray(z),
                        axis_parent=jnp.asarray(z), axis_child=jnp.asarray(z), rest=jnp.zeros((0, 4)), limited=(),
                        lower=jnp.zeros((0,)), upper=jnp.zeros((0,)), swing=jnp.zeros((0,)))
    for name, idx in (("parent", joints.parent), ("child", joints.child)):
        if any(i >= bodies.num_bodies for i in idx):
            raise JaxanimError(f"joints.{name}: a body index is out of range for {bodies.num_bodies} bodies")
    _plan(joints.parent, joints.child, bodies.num_bodies)  # raises for a cycle
    dtype = bodies.mass.dtype
    ground = make_ground("none", dtype=dtype) if ground is None else ground
    return PhysicsModel(bodies=bodies, joints=joints, erp=jnp.asarray(erp, dtype), cfm=jnp.asarray(cfm, dtype),
                        ground=ground, scan_levels=bool(scan_levels))


@eqx.filter_jit
def joint_error(model: PhysicsModel, state: BodyState) -> Float[Array, " J"]:
    """Per joint, the distance between its two anchors (meters): the constraint drift (one compiled
    program per model structure; called eagerly it would compile some eighty small ones)."""
    _, _, g = joint_rows(model.joints, state)
    return jnp.linalg.norm(g[:, :3], axis=-1)


