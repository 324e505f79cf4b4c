r"""Static balance by Jacobian-transpose control (course notes §1.O, eqs. 7.10-7.12).

A character standing on both feet holds its pose by stable PD (``spd`` of
:func:`jaxanim.physics.step`) and keeps its whole-body center of mass ``c`` over its feet with a
**virtual force** at ``c``, turned into joint torques of the stance legs by the Jacobian transpose:

.. math::

    f = P \big(k_p (\bar c - c) - k_d \dot c\big), \qquad
    \tau_i = (c - p_i) \times f / n_\text{legs}
    \quad (i \in \text{ankle, knee, hip of each leg})

(eq. 7.10 and 7.12). ``P = I - u u^T`` keeps the horizontal components (``u`` = world up, minus
gravity's direction: ``+Y``), ``c = \sum_b m_b x_b / M`` and ``\dot c = \sum_b m_b v_b / M`` are the
whole-body center of mass and its velocity, ``p_i`` is joint ``i``'s world anchor, and the force is
shared equally by the ``n_\text{legs}`` (two) stance legs. ``\bar c``, the **support center**, is by
default (``support="feet"``) the mean of the feet bodies' centers of mass (bodies named with
``foot_names``: the foot and toe boxes, i.e. the mean of their contact corners) projected on the
ground, recomputed every step; ``support="initial"`` uses instead the center of mass of the given
pose, fixed (a float ``support`` in ``[0, 1]`` blends the two: the weight of the feet center;
it is ``args["support_weight"]``, so it can be swept too).

**A pose that can stand.** A character built in a mocap frame by
:func:`~jaxanim.character.build_character` stands on soles laid flat in that frame, with heels, and
levelled (CMU ``01_01``'s first frame stands as it is: its center of mass is over the heels, and
the left foot, 2 cm higher than the right in the clip, gets a deeper sole). For another pose than
the build pose the soles are usually tilted; :func:`standing_pose` makes the nearest pose that can
stand: feet flat, the body turned about the ankles so that ``c`` is over the feet center, the
lowest point on the ground; the other joint angles are the frame's. Hold a pose with ``kp`` of
several thousand N m / rad: at 1000 the ankles (two in parallel against the gravitational
stiffness ``m g h`` of about 700 N m / rad and the knees in series) give way and the character
topples slowly even with the balance law.

**Signs.** ``tau_i`` is the torque that the leg below joint ``i`` (the foot side, which pushes on
the ground) exerts on the part above it (the center-of-mass side): the torque of ``f`` at ``c``
about ``p_i``. :func:`jaxanim.physics.step` applies ``joint_torque[j]`` as ``+tau`` on
``joints.child[j]`` and ``-tau`` on ``joints.parent[j]``; in a character built by
:func:`jaxanim.character.build_character` the parent is the body nearer the pelvis (root), i.e. the
center-of-mass side, so ``joint_torque[i] = -tau_i``. (:func:`stance_leg_joints` accepts only
joints on the path from a foot to the root, whose child is on the foot side, and returns that
sign, ``-1``, with each joint.)

**Push.** A horizontal push is an external force ``push_force`` (N, world frame) on the center of
mass of body ``push_body`` during ``push_start <= t < push_start + push_duration`` (``t = k dt``
at step ``k``).

Every gain and the push are arrays in the controller's ``args``, so ``jax.vmap`` sweeps them with a
single compilation (see ``examples/balance_sweep.py``).
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._errors import JaxanimError
from .. import rotations as rot
from ._build import Character, character_state, spd_targets
from .._linalg import dot, matmul
from ..physics._contact import contact_geometry, contact_points
from ..kinematics._fk import forward_kinematics, global_to_local
from ..physics._joints import Joints
from ..physics._bodies import BodyState, RigidBodies, bodies_center_of_mass
from ..physics._control import Control, StablePD

__all__ = [
    "BalanceController", "balance_controller", "bodies_center_of_mass", "joint_anchors", "stance_leg_joints",
    "standing_pose", "stood", "support_center",
]

_SUPPORTS = {"feet": 1.0, "initial": 0.0}  # the weight of the feet center in c_bar


center_of_mass = bodies_center_of_mass  # the 0.1 name (jaxanim.balance.center_of_mass)


def joint_anchors(joints: Joints, state: BodyState) -> Float[Array, "J 3"]:
    """Every joint's anchor in the world frame (meters), seen from its child body."""
    chi = np.asarray(joints.child, int)
    anchor = joints.anchor_child.astype(state.position.dtype)
    return state.position[chi] + rot.quat_apply(state.orientation[chi], anchor)


def _up(bodies: RigidBodies) -> np.ndarray:
    g = np.asarray(bodies.gravity, float)
    n = np.linalg.norm(g)
    return -g / n if n > 0 else np.array([0.0, 1.0, 0.0])


def _foot_bodies(character: Character, foot_names: Sequence[str]) -> list[int]:
    names = character.model.bodies.names
    feet = [b for b, n in enumerate(names) if any(s in n for s in foot_names)]
    if not feet:
        raise JaxanimError(f"foot_names: no body name contains any of {tuple(foot_names)!r}; bodies are {names!r}")
    return feet


def support_center(
    character: Character, state: BodyState, *, foot_names: Sequence[str] = ("Foot", "Toe")
) -> Float[Array, " 3"]:
    """The support center ``c_bar``: the mean of the feet bodies' centers (bodies whose names contain
    one of ``foot_names``), projected on the horizontal plane through the origin (height 0 along
    up; only the horizontal components are used by the balance law)."""
    feet = _foot_bodies(character, foot_names)
    up = jnp.asarray(_up(character.model.bodies), state.position.dtype)
    return _feet_center(state, tuple(feet), up)


support_centre = support_center  # the 0.1 spelling (jaxanim.balance.support_centre)


def _feet_center(state: BodyState, feet: tuple[int, ...], up: Array) -> Array:
    p = jnp.mean(state.position[np.asarray(feet)], axis=0)
    return p - dot(p, up) * up


def stance_leg_joints(
    character: Character,
    *,
    ankle_names: Sequence[str] = ("Foot", "Ankle"),
    exclude_names: Sequence[str] = ("Toe",),
    chain_length: int = 3,
    leg_joints: Sequence[Sequence[str]] | None = None,
) -> tuple[tuple[tuple[int, ...], ...], tuple[tuple[int, ...], ...]]:
    """The joints of each stance leg and the sign that turns the leg torque into ``joint_torque``.

    By default every joint whose name contains one of ``ankle_names`` and none of ``exclude_names``
    is an ankle (CMU: ``LeftFoot``, ``RightFoot``), and its leg is the ankle and the next
    ``chain_length - 1`` joints towards the root (knee ``LeftLeg``, hip ``LeftUpLeg``).
    ``leg_joints`` gives the legs explicitly by joint name instead, e.g.
    ``(("LeftFoot", "LeftLeg", "LeftUpLeg"), ("RightFoot", "RightLeg", "RightUpLeg"))``: each
    joint must lie between that leg's first joint (its lowest) and the root.

    Returns:
        ``(legs, signs)``: per leg the joint indices (ankle first) and, per joint, the sign that
        turns the leg torque into ``joint_torque``: ``-1``, the joint's child being on the foot
        side (``joint_torque = -tau``, see the module docstring).

    Raises:
        JaxanimError: no ankle found, an unknown joint name (the valid ones are listed), or a
            joint that is not on its leg's path to the root.
    """
    joints = character.model.joints
    names = joints.names
    parent_joint = {c: j for j, c in enumerate(joints.child)}  # body -> the joint above it

    def path_up(j0: int) -> list[int]:  # joints from j0 to the root
        out, j = [], j0
        while j is not None:
            out.append(j)
            j = parent_joint.get(joints.parent[j])
        return out

    if leg_joints is None:
        if not isinstance(chain_length, (int, np.integer)) or chain_length < 1:
            raise JaxanimError(f"chain_length: expected an int >= 1, got {chain_length!r}")
        ankles = [j for j, n in enumerate(names)
                  if any(s in n for s in ankle_names) and not any(s in n for s in exclude_names)]
        if not ankles:
            raise JaxanimError(f"ankle_names: no joint name contains any of {tuple(ankle_names)!r} (excluding "
                               f"{tuple(exclude_names)!r}); joints are {names!r}. Pass leg_joints= explicitly.")
        legs = tuple(tuple(path_up(a)[:chain_length]) for a in ankles)
        return legs, tuple(tuple(-1 for _ in leg) for leg in legs)
    legs, signs = [], []
    for leg in leg_joints:
        if isinstance(leg, str) or not len(leg):
            raise JaxanimError(f"leg_joints: expected a sequence of legs, each a non-empty sequence of joint names, "
                               f"got {leg_joints!r}")
        idx = []
        for n in leg:
            if n not in names:
                raise JaxanimError(f"leg_joints: unknown joint {n!r}; joints are {names!r}")
            idx.append(names.index(n))
        path = path_up(idx[0])
        for n, j in zip(leg, idx):
            if j not in path:
                raise JaxanimError(f"leg_joints: joint {n!r} is not between {leg[0]!r} and the root")
        legs.append(tuple(idx))
        signs.append(tuple(-1 for _ in idx))
    return tuple(legs), tuple(signs)


def _body_index(character: Character, body) -> int:
    names = character.model.bodies.names
    if isinstance(body, str):
        if body not in names:
            raise JaxanimError(f"push body: unknown body {body!r}; bodies are {names!r}")
        return names.index(body)
    b = int(body)
    if not 0 <= b < len(names):
        raise JaxanimError(f"push body: expected an index in [0, {len(names)}), got {body!r}")
    return b


def balance_controller(
    character: Character,
    rotations: Float[ArrayLike, "joints 4"],
    translations: Float[ArrayLike, "joints 3"] | None,
    dt: float,
    *,
    kp: Float[ArrayLike, "#J"] = 5000.0,
    kd: Float[ArrayLike, "#J"] = 500.0,
    balance_kp: Float[ArrayLike, ""] = 3000.0,
    balance_kd: Float[ArrayLike, ""] = 600.0,
    max_force: Float[ArrayLike, ""] = np.inf,
    push: tuple | None = None,
    support: str | float = "feet",
    foot_names: Sequence[str] = ("Foot", "Toe"),
    ankle_names: Sequence[str] = ("Foot", "Ankle"),
    chain_length: int = 3,
    leg_joints: Sequence[Sequence[str]] | None = None,
) -> tuple[BalanceController, dict]:
    """A static-balance controller for :func:`jaxanim.physics.rollout` (see the module docstring).

    Every step it returns a :class:`~jaxanim.physics.Control` with ``spd = StablePD(targets, kp, kd)``: stable PD holding the pose
    ``(rotations, translations)`` (:func:`jaxanim.character.spd_targets`); ``joint_torque [J, 3]``:
    the Jacobian-transpose torques of the virtual force on the stance legs (zero elsewhere); and
    ``force [B, 3]``: the push (zero outside its time window). No root force ("servo") is used.

    Args:
        character: the :class:`~jaxanim.character.Character`.
        rotations, translations: the pose to hold (file units), e.g. a clip's first frame.
        dt: the control step, seconds (the rollout's ``dt``; used for the push timing).
        kp, kd: stable-PD gains, N m / rad and N m s / rad, scalar or per joint ``[J]`` (defaults
            5000 and 500: stiff enough to stand, see the module docstring).
        balance_kp, balance_kd: the virtual force's gains, N/m and N s/m (defaults 3000 and 600:
            with 1000 and 200 the CMU character overshoots after a 150 N, 0.2 s push and falls).
        max_force: the virtual force's norm is clipped to this (N; default no clipping).
        push: ``None`` (no push) or ``(force [3] (N, world frame), body (name or index), start (s),
            duration (s))``. Without a push the ``args`` still carry a zero push, so pushed and
            unpushed runs share one compiled rollout.
        support: ``"feet"`` (``c_bar`` = mean of the feet bodies' centers, every step),
            ``"initial"`` (the pose's center of mass) or a weight in ``[0, 1]`` of the feet center
            in a blend of the two (``args["support_weight"]``).
        foot_names: substrings of the feet bodies' names (for ``support="feet"``).
        ankle_names, chain_length, leg_joints: which joints carry the leg torques (see
            :func:`stance_leg_joints`).

    Returns:
        ``(controller, args)`` for ``rollout(..., controller=controller, controller_args=args)``:
        the :class:`BalanceController` (it returns a :class:`~jaxanim.physics.Control`; two calls
        on the same character give controllers of the same structure, so the rollout compiles
        once) and ``args``, a dict of arrays: ``kp``, ``kd`` ``[J]``; ``balance_kp``, ``balance_kd``,
        ``max_force``; ``push_force [3]``, ``push_body`` (int), ``push_start``, ``push_duration``;
        ``target [3]`` (``c_bar`` for ``support="initial"``, unused for ``"feet"``). ``vmap`` over
        any of them sweeps it without recompiling.

    Raises:
        JaxanimError: an unknown ``support``, a bad push, or no feet / legs found by name.
    """
    if isinstance(support, str) and support not in _SUPPORTS or not isinstance(support, str) and not 0 <= support <= 1:
        raise JaxanimError(f"support: expected one of {tuple(_SUPPORTS)} or a weight in [0, 1], got {support!r}")
    if not dt > 0:
        raise JaxanimError(f"dt: expected > 0, got {dt!r}")
    model = character.model
    bodies, joints = model.bodies, model.joints
    dtype = bodies.mass.dtype
    Jn = joints.num_joints
    legs, signs = stance_leg_joints(character, ankle_names=ankle_names, chain_length=chain_length,
                                    leg_joints=leg_joints)
    _foot_bodies(character, foot_names)  # raises when no body is a foot
    # Per joint: the weight of the virtual force it carries (sign / number of legs), zero off the legs.
    weight = np.zeros(Jn)
    for leg, sg in zip(legs, signs):
        for j, s in zip(leg, sg):
            weight[j] += s / len(legs)
    weight = jnp.asarray(weight, dtype)
    up = jnp.asarray(_up(bodies), dtype)
    horizontal = jnp.eye(3, dtype=dtype) - jnp.outer(up, up)
    targets = spd_targets(character, rotations, translations)
    c0, _ = bodies_center_of_mass(bodies, character_state(character, rotations, translations))
    if push is None:
        push = (np.zeros(3), 0, 0.0, 0.0)
    if not (isinstance(push, (tuple, list)) and len(push) == 4):
        raise JaxanimError("push: expected (force [3], body (name or index), start, duration) or None")
    p_force = jnp.asarray(push[0], dtype)
    if p_force.shape != (3,):
        raise JaxanimError(f"push force: expected shape (3,), got {p_force.shape}")
    args = dict(
        kp=jnp.broadcast_to(jnp.asarray(kp, dtype), (Jn,)),
        kd=jnp.broadcast_to(jnp.asarray(kd, dtype), (Jn,)),
        balance_kp=jnp.asarray(balance_kp, dtype), balance_kd=jnp.asarray(balance_kd, dtype),
        max_force=jnp.asarray(max_force, dtype),
        push_force=p_force, push_body=jnp.asarray(_body_index(character, push[1]), jnp.int32),
        push_start=jnp.asarray(push[2], dtype), push_duration=jnp.asarray(push[3], dtype),
        target=c0, support_weight=jnp.asarray(_SUPPORTS[support] if isinstance(support, str) else support, dtype),
    )
    feet = tuple(_foot_bodies(character, foot_names))
    controller = BalanceController(bodies=bodies, joints=joints, feet=feet, targets=targets, weight=weight, up=up,
                                   horizontal=horizontal, dt=jnp.asarray(float(dt)))
    return controller, args


class BalanceController(eqx.Module):
    """The controller of :func:`balance_controller` (a Module, so that two controllers of the same
    character share one compiled rollout; the gains and the push are in its ``args``).

    Attributes:
        bodies, joints: the character's bodies and joints.
        feet: the feet bodies (static), whose mean center is the support center.
        targets: ``[joints, 4]`` the stable-PD targets of the pose held.
        weight: ``[joints]`` the share of the virtual force's torque each joint carries (sign /
            number of legs; zero off the stance legs).
        up: ``[3]`` world up; horizontal: ``[3, 3]`` the projection ``I - u u'``.
        dt: the control step, seconds (for the push timing).
    """

    bodies: RigidBodies
    joints: Joints
    feet: tuple[int, ...] = eqx.field(static=True)
    targets: Float[Array, "joints 4"]
    weight: Float[Array, " joints"]
    up: Float[Array, " 3"]
    horizontal: Float[Array, "3 3"]
    dt: Float[Array, ""]

    def __call__(self, state: BodyState, step, args) -> Control:
        """The :class:`~jaxanim.physics.Control` of step ``step`` with the gains and push ``args``."""
        c, c_dot = bodies_center_of_mass(self.bodies, state)
        w = args["support_weight"]
        c_bar = w * _feet_center(state, self.feet, self.up) + (1.0 - w) * args["target"]
        f = matmul(self.horizontal, args["balance_kp"] * (c_bar - c) - args["balance_kd"] * c_dot)
        norm = jnp.linalg.norm(f)
        f = f * jnp.minimum(1.0, args["max_force"] / jnp.maximum(norm, jnp.finfo(f.dtype).tiny))
        p_world = joint_anchors(self.joints, state)
        tau = jnp.cross(c[None, :] - p_world, f[None, :]) * self.weight[:, None]  # sign_i tau_i / n_legs
        t = step * self.dt
        on = (t >= args["push_start"]) & (t < args["push_start"] + args["push_duration"])
        body_ids = jnp.arange(self.bodies.num_bodies)
        force = jnp.where((body_ids == args["push_body"])[:, None] & on, args["push_force"][None, :], 0.0)
        return Control(force=force, joint_torque=tau, spd=StablePD(self.targets, args["kp"], args["kd"]))


@eqx.filter_jit
def _standing_measures(character: Character, R, P, up, feet: tuple[int, ...]):
    """For global rotations ``R [J, 3, 3]`` and positions ``P [J, 3]`` (file units): the local pose,
    the support center minus the center of mass, and every contact point's height (one program: the
    Newton iterations of :func:`standing_pose` evaluate it a few dozen times)."""
    qs, ts = global_to_local(character.skeleton, R, P)
    s = character_state(character, qs, ts)
    c, _ = bodies_center_of_mass(character.model.bodies, s)
    _, _, phi, _ = contact_geometry(character.model.ground, character.model.bodies, s)
    return qs, ts, _feet_center(s, feet, up) - c, phi


def _ankles(skel, ankle_names, exclude_names) -> tuple[list[int], np.ndarray]:
    """The ankle joints (by name) and, per joint, the ankle it hangs below (-1: above the ankles)."""
    ankles = [j for j, n in enumerate(skel.names)
              if any(s in n for s in ankle_names) and not any(s in n for s in exclude_names)]
    if not ankles:
        raise JaxanimError(f"ankle_names: no skeleton joint name contains any of {tuple(ankle_names)!r}; joints are "
                           f"{skel.names!r}")
    below = np.zeros(skel.num_joints, int) - 1
    for j in range(skel.num_joints):
        a = j
        while a >= 0 and a not in ankles:
            a = skel.parents[a]
        below[j] = a
    return ankles, below


def _flat_feet(character: Character, R0: np.ndarray, below: np.ndarray, up: np.ndarray, foot_names) -> dict:
    """Per foot body's joint, the world rotation that lays its box (length along body z, width along
    body x) flat, keeping the box's own up side up."""
    skel = character.skeleton
    index = {j: b for b, j in enumerate(character.body_joint)}
    flat = {}
    for j in range(skel.num_joints):
        if not (below[j] >= 0 and j in index and any(s in skel.names[j] for s in foot_names)):
            continue
        Rb = R0[j] @ np.asarray(rot.quat_to_matrix(character.body_rotation[index[j]]))
        z = Rb[:, 2] - (Rb[:, 2] @ up) * up
        z /= np.linalg.norm(z)
        x = np.cross(up, z)
        target = np.stack([x, up, z], axis=1)
        if Rb[:, 1] @ up < 0:  # a half turn about z otherwise
            target = np.stack([-x, -up, z], axis=1)
        flat[j] = target @ Rb.T
    return flat


def standing_pose(
    character: Character,
    rotations: Float[ArrayLike, "joints 4"],
    translations: Float[ArrayLike, "joints 3"] | None = None,
    *,
    foot_names: Sequence[str] = ("Foot", "Toe"),
    ankle_names: Sequence[str] = ("Foot", "Ankle"),
    exclude_names: Sequence[str] = ("Toe",),
    lean: bool = True,
    clearance: float = 0.0,
    iterations: int = 8,
) -> tuple[Array, Array]:
    """A pose close to ``(rotations, translations)`` that stands statically on flat ground.

    Mocap frames rarely balance the simulated body when it was built in another pose: its soles are
    flat in the build pose only (see the module docstring). This host-side helper

    1. turns each foot body (the bodies named with ``foot_names`` at or below the ankles, the
       skeleton joints named with ``ankle_names`` and not ``exclude_names``) so that its box lies
       flat: its length and width axes horizontal;
    2. with ``lean``, turns the whole body about the ankles' midpoint (the feet are flattened again
       after the turn): a pitch about the horizontal axis normal to ``c_bar - c`` until the
       horizontal center of mass ``c`` sits on the support center ``c_bar`` along that direction
       (:func:`support_center`) and, with two ankles, a roll about ``c_bar - c`` until both feet
       are equally low (Newton iterations with finite differences);
    3. moves the pose along the ground's normal so that its lowest contact point is ``clearance`` meters above
       the character's ground plane.

    Joint angles other than the ankles' and toes' are unchanged. With unequal legs the roll leaves
    ``c`` to one side of ``c_bar`` (7 cm for CMU ``01_01``, inside the support polygon).

    Returns:
        ``(rotations [joints, 4], translations [joints, 3])`` in file units.

    Raises:
        JaxanimError: no ankle joint found by name.
    """
    skel = character.skeleton
    J = skel.num_joints
    up = _up(character.model.bodies)
    q = skel.rest_rotations(jnp.float64) if rotations is None else jnp.asarray(rotations, jnp.float64)
    t = None if translations is None else jnp.asarray(translations, jnp.float64)
    fk = forward_kinematics(skel, q, t)
    R0 = np.asarray(fk.rotations, float)
    P0 = np.asarray(fk.positions, float) * character.unit
    ankles, below = _ankles(skel, ankle_names, exclude_names)
    flat = _flat_feet(character, R0, below, up, foot_names)  # (1) flat feet

    feet = tuple(_foot_bodies(character, foot_names))
    cbody = np.asarray(contact_points(character.model.bodies)[0])
    up_arr = jnp.asarray(up, jnp.float64)

    def pose(rotvec: np.ndarray):
        """``(rotations, translations, c_bar - c [3], contact heights [K])`` of the pose turned by ``rotvec``."""
        pivot = np.mean(P0[ankles], axis=0)
        Rl = np.asarray(rot.rotvec_to_matrix(jnp.asarray(rotvec)))
        R = np.einsum("ij,njk->nik", Rl, R0)
        P = pivot + (P0 - pivot) @ Rl.T
        F = {}
        for j in range(J):  # parents first
            if below[j] < 0:
                continue
            p = skel.parents[j]
            F[j] = flat.get(j, F.get(p, np.eye(3)))
            R[j] = F[j] @ R0[j]
            if j not in ankles:
                P[j] = P[p] + R[p] @ R0[p].T @ (P0[j] - P0[p])
        qs, ts, offset, heights = _standing_measures(character, jnp.asarray(R), jnp.asarray(P / character.unit), up_arr,
                                                     feet)
        return qs, ts, np.asarray(offset), np.asarray(heights)

    body_below = np.asarray([below[j] for j in character.body_joint])

    def residual(theta: np.ndarray, d: np.ndarray):
        # [c_bar - c along d, height of the first foot's lowest point minus the second's]
        qs, ts, offset, h = pose(theta[0] * np.cross(up, d) + theta[1] * d)
        r = [float(offset @ d)]
        if len(ankles) == 2:
            r.append(float(h[body_below[cbody] == ankles[0]].min() - h[body_below[cbody] == ankles[1]].min()))
        return np.asarray(r), (qs, ts, h)

    qs, ts, e, h = pose(np.zeros(3))
    e = e - (e @ up) * up
    if lean and np.linalg.norm(e) > 1e-9:
        d = e / np.linalg.norm(e)
        theta = np.zeros(2)
        for _ in range(iterations):  # Newton with forward differences (two unknowns: pitch, roll)
            r, (qs, ts, h) = residual(theta, d)
            if np.max(np.abs(r)) < 1e-6:
                break
            n = r.size
            Jac = np.stack([(residual(theta + 1e-4 * np.eye(2)[k], d)[0] - r) / 1e-4 for k in range(n)], axis=1)
            theta[:n] = theta[:n] - np.linalg.solve(Jac, r)
        else:
            r, (qs, ts, h) = residual(theta, d)
    # (3) Vertical placement.
    low = float(h.min())
    root = [j for j in range(J) if skel.parents[j] < 0]
    shift = (clearance - low) * np.asarray(character.model.ground.normal, float) / character.unit
    ts = ts.at[np.asarray(root)].add(jnp.asarray(shift, ts.dtype))
    return qs, ts


def stood(
    character: Character, initial: BodyState, trajectory: BodyState, *, height_tolerance: float = 0.05
) -> Array:
    """Whether the character stayed up: its center of mass never fell below ``1 - height_tolerance``
    of its initial height (along up) in the recorded ``trajectory`` (leading time axis). A scalar
    bool; ``vmap`` it over a batch of rollouts."""
    up = jnp.asarray(_up(character.model.bodies), initial.position.dtype)
    c0, _ = bodies_center_of_mass(character.model.bodies, initial)
    heights = matmul(jax.vmap(lambda s: bodies_center_of_mass(character.model.bodies, s)[0])(trajectory), up)
    return jnp.all(heights >= (1.0 - height_tolerance) * dot(c0, up))
