r"""A simulated character built from a :class:`~jaxanim.skeleton.Skeleton`: one rigid body per bone
group, ball joints at the skeleton's joints, and the maps between BVH poses and body states.

**Bodies.** The segment of joint ``j`` is made of its children's (and End Sites') offsets, which
all turn with ``j``'s rotation (the convention of :func:`jaxanim.fk.segment_com_offsets`). A joint
whose segment has a non-negligible length (more than ``min_length`` of the height) gets a body:
a capsule along the mean child direction whose tip-to-tip length is the mean offset length and
whose radius comes from the joint's name (rough human proportions of the height: torso 0.08,
head 0.06, thigh 0.05, shank 0.04, upper arm 0.035, forearm 0.03, hand 0.02; other names
``radius_ratio`` times the length, clamped to ``[0.025, 0.07]`` of the height); feet and toes
(names containing ``foot_names``) get **soles**: boxes laid flat in the pose the character is built
in (along the segment's horizontal heading, the bottom 0.6 r below the segment's lower end); a
foot's sole (one whose parent is not a sole) reaches back past the ankle for a heel (``heel``,
0.35 of its length: the ankle sits over the back third of a human foot), and soles that end up
less than ``sole_fit`` (3 cm) above the lowest one are deepened to its level, so that a mocap
frame of a standing subject stands on both feet. (A sole whose segment is steeper than 60 degrees
in the build pose stays a box along the segment.)
Masses are proportional to the shapes' volumes and sum to ``total_mass`` (default 70 kg).
Bodiless joints (zero-length segments, as CMU's ``Hips``, ``LHipJoint``'s parent and the chest
junction) are welded into the nearest ancestor with a body; bodies with no such ancestor hang off
the heaviest of them, the root body, which is free.

**Joints.** Each non-root body is attached to its nearest bodied ancestor by a ball joint at its
joint's position.

**Units.** Simulation is in meters, seconds and kilograms with gravity ``-9.81`` along ``+Y``
(BVH's up axis). The file's unit is inferred from the skeleton's rest height (``height``, default
1.7 m) unless ``unit`` (meters per file unit) is given; :func:`character_pose` writes poses back
in file units.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .. import rotations as rot
from .._errors import JaxanimError, check_shape
from .._linalg import einsum
from ..kinematics._fk import forward_kinematics
from ..physics._bodies import BodyState, RigidBodies, make_bodies, make_state, shape_mass_properties
from ..physics._contact import Ground
from ..physics._control import Control, Servo, StablePD
from ..physics._joints import Joints, make_joints
from ..physics._mjcf import to_mjcf
from ..physics._model import PhysicsModel, make_model
from ..skeleton._skeleton import Skeleton

__all__ = [
    "Character", "TrackingController", "build_character", "character_pose", "character_state", "export_mjcf",
    "root_body", "spd_targets", "tracking_controller",
]


class Character(eqx.Module):
    """A skeleton's physics model and the maps between its poses and body states.

    Attributes:
        model: the :class:`~jaxanim.physics.PhysicsModel` (meters, kg).
        skeleton: the skeleton (file units).
        body_joint: ``[nb]`` the skeleton joint that owns each body (static).
        joint_body: ``[joints]`` the body each skeleton joint moves with (its own, or its nearest
            bodied ancestor's; ``-1`` for bodiless joints above every body) (static).
        unit: meters per file unit (static).
        body_rotation: ``[nb, 4]`` each body's orientation in its joint's frame (wxyz).
        body_center: ``[nb, 3]`` each body's center of mass in its joint's frame, meters.
    """

    model: PhysicsModel
    skeleton: Skeleton
    body_joint: tuple[int, ...] = eqx.field(static=True)
    joint_body: tuple[int, ...] = eqx.field(static=True)
    unit: float = eqx.field(static=True)
    body_rotation: Float[Array, "nb 4"]
    body_center: Float[Array, "nb 3"]

    @property
    def num_bodies(self) -> int:
        return len(self.body_joint)

    @property
    def body_centre(self) -> Float[Array, "nb 3"]:
        """The 0.1 spelling of :attr:`body_center`."""
        return self.body_center


def _segments(skeleton: Skeleton, j: int) -> np.ndarray:
    off = np.asarray(skeleton.offsets, float)
    es = np.asarray(skeleton.end_site_offsets, float)
    parts = [off[c] for c, p in enumerate(skeleton.parents) if p == j]
    parts += [es[e] for e, p in enumerate(skeleton.end_site_parents) if p == j]
    return np.asarray(parts, float).reshape(-1, 3)


# Segment radius as a fraction of the height, by the first matching (lower-case) name fragment;
# rough human proportions. Other names: radius_ratio x length, clamped to [0.025, 0.07] x height.
_RADII = (
    (("finger", "thumb", "hand", "wrist"), 0.02),
    (("forearm", "elbow"), 0.03),
    (("shoulder", "clavicle", "collar"), 0.035),
    (("arm",), 0.035),
    (("upleg", "thigh"), 0.05),
    (("leg", "shin", "calf", "knee"), 0.04),
    (("foot", "ankle", "toe"), 0.03),
    (("head",), 0.06),
    (("neck",), 0.035),
    (("spine", "back", "chest", "torso", "abdomen", "pelvis", "hip"), 0.08),
)


def _radius(name: str, length: float, height: float, ratio: float) -> float:
    low = name.lower()
    for keys, frac in _RADII:
        if any(k in low for k in keys):
            return frac * height
    return float(np.clip(ratio * length, 0.025 * height, 0.07 * height))


def _body_shapes(skeleton: Skeleton, p_world, R_world, unit: float, H: float, *, radius_ratio, min_length,
                 foot_names, heel, sole_fit):
    """The bodies of the joints with a segment, in the build pose ``(p_world [joints, 3] (meters),
    R_world [joints, 3, 3])``: ``(body_joint, shapes, centers [3] in the joint frames, rotations
    (quaternions) in the joint frames)`` (see the module docstring).

    Raises:
        JaxanimError: no segment is longer than ``min_length``.
    """
    J = skeleton.num_joints
    up = np.array([0.0, 1.0, 0.0])
    # Bodies: shapes in the joint frames (meters).
    body_joint, shapes, centers, body_rots = [], [], [], []
    soles = []  # (body, bottom height in the build pose)
    for j in range(J):
        seg = _segments(skeleton, j) * unit
        lengths = np.linalg.norm(seg, axis=1)
        seg = seg[lengths > min_length * H]
        if seg.shape[0] == 0:
            continue
        mean = seg.mean(axis=0)
        if np.linalg.norm(mean) > 0.5 * np.linalg.norm(seg, axis=1).mean():
            d, L = mean / np.linalg.norm(mean), float(np.linalg.norm(mean))
        else:  # children spread symmetrically: along the longest
            k = int(np.argmax(np.linalg.norm(seg, axis=1)))
            L = float(np.linalg.norm(seg[k]))
            d = seg[k] / L
        r = _radius(skeleton.names[j], L, H, radius_ratio)
        body_joint.append(j)
        is_foot = any(s in skeleton.names[j] for s in foot_names)
        s_w = R_world[j] @ (L * d)  # the segment in the build pose
        s_h = s_w - (s_w @ up) * up
        if is_foot and np.linalg.norm(s_h) > 0.5 * L:
            # A sole: a box lying flat in the build pose along the segment's heading, its bottom
            # 0.6 r below the segment's lower end; a foot (not a toe) reaches `heel` of its length
            # behind the joint.
            Lh = float(np.linalg.norm(s_h))
            parent = skeleton.parents[j]
            back = heel * Lh if parent < 0 or not any(s in skeleton.names[parent] for s in foot_names) else 0.0
            z = s_h / Lh
            shapes.append(["box", [2 * r, 1.2 * r, Lh + back]])
            centers.append(0.5 * (Lh - back) * z + min(0.0, float(s_w @ up)) * up)  # world, fixed below
            body_rots.append(np.stack([np.cross(up, z), up, z], axis=1))  # world; local below
            soles.append((len(body_joint) - 1, float(p_world[j] @ up + centers[-1] @ up) - 0.6 * r))
            continue
        if is_foot:
            shapes.append(("box", (2 * r, 1.2 * r, L)))
        else:
            shapes.append(("capsule", (r, max(L - 2 * r, 0.2 * L))))
        centers.append(0.5 * L * d)
        body_rots.append(d)  # the capsule's axis; a rotation below
    # Soles within `sole_fit` above the lowest one reach down to it (mocap feet are rarely level).
    level = min((h for _, h in soles), default=0.0)
    for b, h in soles:
        gap = h - level if h - level <= sole_fit else 0.0
        shapes[b][1][1] += gap
        j = body_joint[b]
        centers[b] = R_world[j].T @ (centers[b] - 0.5 * gap * up)
        body_rots[b] = R_world[j].T @ body_rots[b]
        shapes[b] = (shapes[b][0], tuple(shapes[b][1]))
    if not body_joint:
        raise JaxanimError("skeleton: no segment longer than min_length; nothing to simulate")
    # Body orientations in their joints' frames, each kind in one call.
    quats = np.zeros((len(body_joint), 4))
    sole = np.array([np.ndim(R) == 2 for R in body_rots])
    if sole.any():
        quats[sole] = np.asarray(_matrix_to_quat(jnp.asarray(np.stack([R for R in body_rots if np.ndim(R) == 2]))))
    if (~sole).any():
        axes = jnp.asarray(np.stack([d for d in body_rots if np.ndim(d) == 1]))
        quats[~sole] = np.asarray(_rotation_between(jnp.array([0.0, 0.0, 1.0]), axes))
    body_rots = list(quats)
    return body_joint, shapes, centers, body_rots


def _joint_specs(skeleton: Skeleton, body_joint, joint_body, masses, p_world) -> list[dict]:
    """Ball joints to the nearest bodied ancestor, at the joints' positions; top-level bodies hang
    off the heaviest one (the root body, left free)."""
    top = [b for b, j in enumerate(body_joint) if skeleton.parents[j] < 0 or joint_body[skeleton.parents[j]] < 0]
    root = max(top, key=lambda b: masses[b])
    specs = []
    for b, j in enumerate(body_joint):
        if b == root:
            continue
        parent = root if b in top else joint_body[skeleton.parents[j]]
        specs.append(dict(name=skeleton.names[j], type="ball", parent=int(parent), child=int(b), anchor=p_world[j]))
    return specs


def build_character(
    skeleton: Skeleton,
    rotations: Float[Array, "joints 4"] | None = None,
    translations: Float[Array, "joints 3"] | None = None,
    *,
    total_mass: float = 70.0,
    height: float = 1.7,
    unit: float | None = None,
    radius_ratio: float = 0.2,
    min_length: float = 0.035,
    foot_names: tuple[str, ...] = ("Foot", "Toe"),
    heel: float = 0.35,
    sole_fit: float = 0.03,
    ground: Ground | None = None,
    erp: float = 0.5,
    cfm: float = 1e-10,
    scan_levels: bool = False,
) -> tuple[Character, BodyState]:
    """Build the character and its state at a pose (default: the rest pose).

    Args:
        skeleton: the skeleton (any unit).
        rotations, translations: the pose to assemble in (file units; default rest).
        total_mass: kg.
        height: the rest-pose height in meters that sets the unit when ``unit`` is omitted.
        unit: meters per file unit.
        radius_ratio: capsule radius / segment length (then clamped, see the module docstring).
        min_length: segments shorter than this fraction of the height are ignored.
        foot_names: substrings of joint names whose bodies are boxes (soles, see the module
            docstring).
        heel: a foot's heel length behind its joint, as a fraction of the foot's length.
        sole_fit: meters; soles less than this above the lowest one in the build pose are
            deepened to reach its level (0: no fitting).
        ground: the ground contact (default none; :func:`jaxanim.contact.make_ground`).
        erp, cfm, scan_levels: as for :func:`jaxanim.physics.make_model`.

    Returns:
        ``(character, state)``: the :class:`Character` and the bodies' state at the pose, at rest.

    Raises:
        JaxanimError: non-positive mass, height or unit, or a skeleton without any segment.
    """
    for name, value in (("total_mass", total_mass), ("height", height), ("radius_ratio", radius_ratio)):
        if not value > 0:
            raise JaxanimError(f"{name}: expected > 0, got {value!r}")
    if not heel >= 0 or not sole_fit >= 0:
        raise JaxanimError(f"heel, sole_fit: expected >= 0, got {heel!r}, {sole_fit!r}")
    if unit is not None and not unit > 0:
        raise JaxanimError(f"unit: expected > 0 (meters per file unit), got {unit!r}")
    J = skeleton.num_joints
    offsets = jnp.broadcast_to(jnp.asarray(skeleton.offsets, jnp.float64), (J, 3))  # = rest translations
    rest = _forward_kinematics(skeleton, skeleton.rest_rotations(jnp.float64), offsets)
    pts = np.concatenate([np.asarray(rest.positions), np.asarray(rest.end_site_positions).reshape(-1, 3)])
    file_height = float(pts[:, 1].max() - pts[:, 1].min())
    if unit is None:
        if not file_height > 0:
            raise JaxanimError("skeleton: zero rest height along Y; give unit= (meters per file unit)")
        unit = height / file_height
    H = file_height * unit  # meters
    # The build pose (world frame, meters): soles are laid flat in it.
    q_build, t_build = _pose(skeleton, rotations, translations)
    fk = _forward_kinematics(skeleton, q_build, offsets if t_build is None else t_build)
    p_world = np.asarray(fk.positions) * unit
    R_world = np.asarray(fk.rotations)
    body_joint, shapes, centers, body_rots = _body_shapes(skeleton, p_world, R_world, unit, H, radius_ratio=radius_ratio,
                                                          min_length=min_length, foot_names=foot_names, heel=heel,
                                                          sole_fit=sole_fit)
    vols = np.array([float(shape_mass_properties(k, s, density=1.0)[0]) for k, s in shapes])
    masses = total_mass * vols / vols.sum()
    names = tuple(skeleton.names[j] for j in body_joint)
    bodies = make_bodies(shapes, names=names, mass=masses, gravity=(0.0, -9.81, 0.0), dtype=jnp.float64)
    # Which body each joint moves with.
    index = {j: b for b, j in enumerate(body_joint)}
    joint_body = []
    for j in range(J):
        a = j
        while a >= 0 and a not in index:
            a = skeleton.parents[a]
        joint_body.append(index[a] if a >= 0 else -1)
    char = Character(
        model=None, skeleton=skeleton, body_joint=tuple(body_joint), joint_body=tuple(joint_body), unit=float(unit),
        body_rotation=jnp.asarray(np.stack(body_rots)), body_center=jnp.asarray(np.stack(centers)),
    )
    state = character_state(char, rotations, translations, bodies=bodies)
    specs = _joint_specs(skeleton, body_joint, joint_body, masses, p_world)
    joints: Joints = make_joints(bodies, state, specs)
    model = make_model(bodies, joints, ground=ground, erp=erp, cfm=cfm, scan_levels=scan_levels)
    return eqx.tree_at(lambda c: c.model, char, model, is_leaf=lambda x: x is None), state


_forward_kinematics = eqx.filter_jit(forward_kinematics)
_matrix_to_quat = jax.jit(rot.matrix_to_quat)
_rotation_between = jax.jit(rot.rotation_between)


def _pose(skeleton: Skeleton, rotations, translations):
    q = skeleton.rest_rotations(jnp.float64) if rotations is None else jnp.asarray(rotations, jnp.float64)
    check_shape("rotations", q, (skeleton.num_joints, 4), what=f"(joints, 4) = ({skeleton.num_joints}, 4)")
    t = None if translations is None else jnp.asarray(translations, jnp.float64)
    if t is not None:
        check_shape("translations", t, (skeleton.num_joints, 3), what=f"(joints, 3) = ({skeleton.num_joints}, 3)")
    return q, t


def character_state(
    character: Character,
    rotations: Float[Array, "joints 4"] | None = None,
    translations: Float[Array, "joints 3"] | None = None,
    *,
    bodies: RigidBodies | None = None,
) -> BodyState:
    """The bodies' state (at rest) for a pose of the skeleton (file units)."""
    q, t = _pose(character.skeleton, rotations, translations)
    bodies = character.model.bodies if bodies is None else bodies
    return _character_state(character, q, t, bodies)


@eqx.filter_jit
def _character_state(character: Character, q, t, bodies: RigidBodies) -> BodyState:
    skel = character.skeleton
    fk = forward_kinematics(skel, q, t)
    bj = np.asarray(character.body_joint)
    R = fk.rotations[bj]
    x = fk.positions[bj] * character.unit + einsum("bij,bj->bi", R, character.body_center)
    orientation = rot.quat_multiply(rot.matrix_to_quat(R), character.body_rotation)
    return make_state(bodies, position=x, orientation=orientation)


def character_pose(
    character: Character, state: BodyState, reference: Float[Array, "joints 4"] | None = None
) -> tuple[Float[Array, "joints 4"], Float[Array, "joints 3"]]:
    """The skeleton pose ``(rotations [joints, 4], translations [joints, 3])`` (file units) of a body
    state: each bodied joint's world rotation is its body's, a bodiless joint keeps its
    ``reference`` local rotation (default rest), and the root's translation follows from the
    bodies."""
    skel = character.skeleton
    J = skel.num_joints
    ref = skel.rest_rotations(state.position.dtype) if reference is None else jnp.asarray(reference)
    bj = np.asarray(character.body_joint)
    q_body_joint = rot.quat_multiply(state.orientation, rot.quat_conjugate(character.body_rotation))
    p_body_joint = state.position - rot.quat_apply(q_body_joint, character.body_center)
    own = {int(j): b for b, j in enumerate(bj)}
    # World rotations top-down (parents precede children in a Skeleton).
    q_world: list = [None] * J
    for j in range(J):
        p = skel.parents[j]
        if j in own:
            q_world[j] = q_body_joint[own[j]]
        elif p >= 0:
            q_world[j] = rot.quat_multiply(q_world[p], ref[j])
    # Bodiless joints above every body (e.g. the root): from the first bodied descendant.
    for j in reversed(range(J)):
        if q_world[j] is None:
            kids = [c for c, p in enumerate(skel.parents) if p == j and q_world[c] is not None]
            q_world[j] = rot.quat_multiply(q_world[kids[0]], rot.quat_conjugate(ref[kids[0]]))
    qw = jnp.stack(q_world)
    local = jnp.stack([qw[j] if skel.parents[j] < 0 else rot.quat_multiply(rot.quat_conjugate(qw[skel.parents[j]]), qw[j])
                       for j in range(J)])
    # Root translation: a bodied joint's world position minus its offsets up the chain.
    b0 = 0
    j0 = int(bj[b0])
    p = p_body_joint[b0] / character.unit
    a = j0
    while skel.parents[a] >= 0:
        par = skel.parents[a]
        p = p - rot.quat_apply(qw[par], skel.offsets[a].astype(p.dtype))
        a = par
    translations = jnp.broadcast_to(skel.offsets.astype(p.dtype), (J, 3)).at[a].set(p)
    return rot.quat_canonical(local), translations


def spd_targets(character: Character, rotations: Float[Array, "joints 4"],
                translations: Float[Array, "joints 3"] | None = None) -> Float[Array, "nj 4"]:
    """Stable-PD targets for the character's physics joints from a skeleton pose: each joint's
    child-body orientation relative to its parent body in that pose (``q_p^{-1} q_c``)."""
    s = character_state(character, rotations, translations)
    joints = character.model.joints
    par = np.asarray(joints.parent)
    chi = np.asarray(joints.child)
    return rot.quat_multiply(rot.quat_conjugate(s.orientation[par]), s.orientation[chi])


@eqx.filter_jit
def clip_targets(character: Character, Q, T):
    """Every frame's SPD targets and body states (one compiled call, not op by op)."""
    return (jax.vmap(lambda q, t: spd_targets(character, q, t))(Q, T),
            jax.vmap(lambda q, t: character_state(character, q, t))(Q, T))


def export_mjcf(character: Character, state: BodyState, *, dt: float = 1 / 600, stiffness=None, damping=None) -> str:
    """The character as MuJoCo XML (see :func:`jaxanim.physics.to_mjcf`; ``stiffness`` and
    ``damping`` hold the joints at the pose of ``state``, the ground plane is exported with
    contacts when the character has one)."""
    return to_mjcf(character.model, state, dt=dt, name="character", stiffness=stiffness, damping=damping)


def root_body(character: Character) -> int:
    """The free body (no joint's child)."""
    children = set(character.model.joints.child)
    return next(b for b in range(character.num_bodies) if b not in children)


class TrackingController(eqx.Module):
    """The controller of :func:`tracking_controller`: a clip's stable-PD targets and root poses,
    looped (a Module, so that two controllers of clips with the same shapes share one compiled
    rollout).

    Attributes:
        root: the root body (static).
        targets: ``[frames, joints, 4]`` every frame's SPD targets (:func:`spd_targets`).
        root_position, root_orientation: ``[frames, 3]``, ``[frames, 4]`` the root body's pose in
            every frame (world frame, m; wxyz).
        dt: the control step, seconds.
        fps: the clip's frame rate.
    """

    root: int = eqx.field(static=True)
    targets: Float[Array, "frames joints 4"]
    root_position: Float[Array, "frames 3"]
    root_orientation: Float[Array, "frames 4"]
    dt: Float[Array, ""]
    fps: Float[Array, ""]

    def __call__(self, state: BodyState, step, args) -> Control:
        """The :class:`~jaxanim.physics.Control` of step ``step`` with the gains ``args``."""
        frames = self.targets.shape[0]
        # + 1e-6: a frame boundary hit exactly
        f = jnp.floor(step * self.dt * self.fps + 1e-6).astype(jnp.int32) % frames
        servo = Servo(self.root, self.root_position[f], self.root_orientation[f], args["root_kp"], args["root_kd"],
                      args["root_angular_kp"], args["root_angular_kd"])
        return Control(spd=StablePD(self.targets[f], args["kp"], args["kd"]), servo=servo)


def tracking_controller(
    character: Character,
    motion,
    dt: float,
    *,
    kp: float = 500.0,
    kd: float = 50.0,
    root_force: bool = True,
    root_kp: float = 200.0,
    root_angular_kp: float = 1000.0,
    root_angular_kd: float = 140.0,
) -> tuple[TrackingController, dict]:
    """A stable-PD controller that tracks ``motion`` (looping) for :func:`jaxanim.physics.rollout`.

    Every step ``k`` takes frame ``floor(k dt fps) mod frames`` of the clip: the joints' SPD
    targets (:func:`spd_targets`) and, with ``root_force``, the root body's pose for an implicit
    "hand of God" servo of stiffness ``root_kp`` per kg of the character (critically damped) and
    ``root_angular_kp`` N m / rad with damping ``root_angular_kd`` N m s / rad.

    Returns:
        ``(controller, args)`` for ``rollout(..., controller=controller, controller_args=args)``:
        the :class:`TrackingController` (it returns a :class:`~jaxanim.physics.Control`; clips
        with the same number of frames on the same character give controllers of the same
        structure, so the rollout compiles once) and ``args``, a dict of arrays (``kp``, ``kd``
        per joint, ``root_kp``, ``root_kd``, ``root_angular_kp``, ``root_angular_kd``), so
        ``vmap`` can sweep the gains.
    """
    targets, states = clip_targets(character, motion.rotations, motion.translations)
    root = root_body(character)
    mass = float(jnp.sum(character.model.bodies.mass))
    nj = character.model.joints.num_joints
    args = dict(
        kp=jnp.full((nj,), kp), kd=jnp.full((nj,), kd),
        root_kp=jnp.asarray(root_kp * mass if root_force else 0.0),
        root_kd=jnp.asarray(2.0 * np.sqrt(root_kp) * mass if root_force else 0.0),
        root_angular_kp=jnp.asarray(root_angular_kp if root_force else 0.0),
        root_angular_kd=jnp.asarray(root_angular_kd if root_force else 0.0),
    )
    controller = TrackingController(root=root, targets=targets, root_position=states.position[:, root],
                                    root_orientation=states.orientation[:, root], dt=jnp.asarray(float(dt)),
                                    fps=jnp.asarray(float(motion.fps)))
    return controller, args
