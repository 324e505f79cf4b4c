"""Skeletons and motion clips as pytrees.

A :class:`Skeleton` holds the static tree structure (names, parents, BVH channel layout, End Sites)
and the numeric rest offsets. A :class:`Motion` holds per-frame local rotations and local
translations plus the frame time. Structure is static (``eqx.field(static=True)``), numbers are
arrays, so a skeleton can be closed over or passed through ``jax.jit`` and ``jax.vmap``.

Conventions (the BVH ones):
    * the local transform of joint ``j`` is ``[R_parent_joint | t_parent_joint]``; ``t`` is the
      joint's OFFSET with each position channel the joint has replacing its own component (a
      joint with all three position channels ignores its OFFSET);
    * rotations are wxyz unit quaternions (or 3x3 matrices) acting on column vectors;
    * global = parent_global @ local; the root's parent is the world;
    * an End Site is named ``<its joint>_End`` and sits at its joint's global transform applied to
      its OFFSET.
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import _tree
from .._errors import JaxanimError, check_shape
from .._types import Array, Float

POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")
ROTATION_CHANNELS = ("Xrotation", "Yrotation", "Zrotation")
VALID_CHANNELS = POSITION_CHANNELS + ROTATION_CHANNELS


def _validate_structure(names, parents, channels, end_site_parents) -> None:
    n = len(parents)
    if n == 0:
        raise JaxanimError("parents: a skeleton needs at least one joint")
    if len(names) != n:
        raise JaxanimError(f"names: expected {n} names (one per parent entry), got {len(names)}")
    if len(set(names)) != n:
        dup = sorted({x for x in names if names.count(x) > 1})
        raise JaxanimError(f"names: joint names must be unique, repeated: {dup}")
    if parents[0] != -1:
        raise JaxanimError(f"parents: joint 0 must be the root (parent -1), got parent {parents[0]}")
    for j, p in enumerate(parents[1:], start=1):
        if not (0 <= p < j):
            raise JaxanimError(
                f"parents: parents must be topologically sorted (0 <= parents[j] < j) with one root; "
                f"joint {j} ({names[j]!r}) has parent {p}"
            )
    if len(channels) != n:
        raise JaxanimError(f"channels: expected {n} channel tuples (one per joint), got {len(channels)}")
    for j, ch in enumerate(channels):
        bad = [c for c in ch if c not in VALID_CHANNELS]
        if bad:
            raise JaxanimError(f"channels: joint {names[j]!r} has unknown channels {bad}; valid: {list(VALID_CHANNELS)}")
        if len(set(ch)) != len(ch):
            raise JaxanimError(f"channels: joint {names[j]!r} repeats a channel: {list(ch)}")
    for e, p in enumerate(end_site_parents):
        if not (0 <= p < n):
            raise JaxanimError(f"end_site_parents: End Site {e} has parent {p}, expected 0 <= parent < {n}")


class Skeleton(eqx.Module):
    """A joint tree with BVH-style channel layout.

    Attributes:
        names: joint names, unique, in topological (file) order. Static.
        parents: parent index of every joint, ``-1`` for the root (joint 0 only), ``parents[j] < j``.
            Static.
        channels: per joint, its BVH channel names in file order, e.g.
            ``("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation")``. Static.
        end_site_parents: the joint each End Site hangs from. Static.
        offsets: ``[joints, 3]`` OFFSET of each joint in its parent's frame (file units).
        end_site_offsets: ``[end_sites, 3]`` OFFSET of each End Site in its joint's frame.
    """

    names: tuple[str, ...] = eqx.field(static=True)
    parents: tuple[int, ...] = eqx.field(static=True)
    channels: tuple[tuple[str, ...], ...] = eqx.field(static=True)
    end_site_parents: tuple[int, ...] = eqx.field(static=True)
    offsets: Float[Array, "joints 3"] = eqx.field(converter=jnp.asarray)
    end_site_offsets: Float[Array, "end_sites 3"] = eqx.field(converter=jnp.asarray)

    def __init__(self, names, parents, offsets, channels=None, end_site_parents=(), end_site_offsets=None):
        """Build a skeleton; ``channels`` defaults to 6 channels (``Xp Yp Zp Zr Yr Xr``) on the root
        and ``Zr Yr Xr`` elsewhere, ``end_site_offsets`` to an empty ``[0, 3]`` array."""
        names = tuple(str(x) for x in names)
        parents = tuple(int(p) for p in np.asarray(parents).reshape(-1).tolist())
        if channels is None:
            channels = tuple(
                (POSITION_CHANNELS + ("Zrotation", "Yrotation", "Xrotation")) if p < 0 else ("Zrotation", "Yrotation", "Xrotation")
                for p in parents
            )
        channels = tuple(tuple(str(c) for c in ch) for ch in channels)
        end_site_parents = tuple(int(p) for p in np.asarray(end_site_parents, dtype=np.int64).reshape(-1).tolist())
        _validate_structure(names, parents, channels, end_site_parents)
        self.names = names
        self.parents = parents
        self.channels = channels
        self.end_site_parents = end_site_parents
        check_shape("offsets", offsets, (len(parents), 3), what=f"(joints, 3) = ({len(parents)}, 3)")
        self.offsets = offsets
        if end_site_offsets is None:
            end_site_offsets = np.zeros((0, 3), dtype=np.asarray(offsets).dtype if hasattr(offsets, "dtype") else float)
        check_shape(
            "end_site_offsets", end_site_offsets, (len(end_site_parents), 3),
            what=f"(end_sites, 3) = ({len(end_site_parents)}, 3)",
        )
        self.end_site_offsets = end_site_offsets

    # --- cheap accessors -------------------------------------------------------------------------
    @property
    def num_joints(self) -> int:
        return len(self.parents)

    @property
    def num_end_sites(self) -> int:
        return len(self.end_site_parents)

    @property
    def end_site_names(self) -> tuple[str, ...]:
        """End Site names, ``<joint>_End``; a joint with several End Sites gets ``_End``, ``_End1``, ..."""
        return _end_site_names(self.names, self.end_site_parents)

    @property
    def rotation_orders(self) -> tuple[str, ...]:
        """Per joint, the axes of its rotation channels in file order, e.g. ``"ZXY"`` (may be ``""``)."""
        return tuple("".join(c[0] for c in ch if c in ROTATION_CHANNELS) for ch in self.channels)

    @property
    def position_axes(self) -> tuple[str, ...]:
        """Per joint, the axes of its position channels in file order, e.g. ``"XYZ"`` (may be ``""``)."""
        return tuple("".join(c[0] for c in ch if c in POSITION_CHANNELS) for ch in self.channels)

    @property
    def has_position_channels(self) -> tuple[bool, ...]:
        return tuple(bool(a) for a in self.position_axes)

    @property
    def num_channels(self) -> int:
        return sum(len(ch) for ch in self.channels)

    @property
    def depths(self) -> tuple[int, ...]:
        """Depth of every joint (root = 0)."""
        return _depths(self.parents)

    @property
    def levels(self) -> tuple[tuple[int, ...], ...]:
        """Joint indices grouped by depth: ``levels[d]`` are the joints at depth ``d``."""
        return _levels(self.parents)

    def index(self, name: str) -> int:
        """Index of a joint by name; raises :class:`JaxanimError` listing valid names."""
        try:
            return self.names.index(name)
        except ValueError:
            raise JaxanimError(f"unknown joint {name!r}; valid joints: {list(self.names)}") from None

    def site_index(self, name: str) -> int:
        """Index into the concatenation ``joints + End Sites`` of a joint or ``<joint>_End`` name."""
        if name in self.names:
            return self.names.index(name)
        es = self.end_site_names
        if name in es:
            return self.num_joints + es.index(name)
        raise JaxanimError(f"unknown joint or End Site {name!r}; valid: {list(self.names) + list(es)}")

    def rest_rotations(self, dtype=None) -> Float[Array, "joints 4"]:
        """Identity quaternions ``[joints, 4]`` (the rest pose: every rotation channel zero)."""
        dtype = dtype or self.offsets.dtype
        return jnp.tile(jnp.array([1.0, 0.0, 0.0, 0.0], dtype=dtype), (self.num_joints, 1))


def _depths(parents: tuple[int, ...]) -> tuple[int, ...]:
    return _tree.depths(parents)


def _levels(parents: tuple[int, ...]) -> tuple[tuple[int, ...], ...]:
    return _tree.levels(parents)


@functools.lru_cache(maxsize=256)
def _end_site_names(names: tuple[str, ...], end_site_parents: tuple[int, ...]) -> tuple[str, ...]:
    out, seen = [], {}
    for p in end_site_parents:
        k = seen.get(p, 0)
        seen[p] = k + 1
        out.append(f"{names[p]}_End" + (str(k) if k else ""))
    return tuple(out)


class Motion(eqx.Module):
    """A clip: per-frame local joint rotations and translations.

    Attributes:
        rotations: ``[frames, joints, 4]`` local rotations, wxyz unit quaternions
            (``R_parent_joint``).
        translations: ``[frames, joints, 3]`` local translations in the parent frame (file units):
            the OFFSET with each position channel's value in place of its component (for a BVH
            root with three position channels: the root translation), the OFFSET for joints
            without position channels.
        frame_time: scalar seconds per frame.
    """

    rotations: Float[Array, "frames joints 4"] = eqx.field(converter=jnp.asarray)
    translations: Float[Array, "frames joints 3"] = eqx.field(converter=jnp.asarray)
    frame_time: Float[Array, ""] = eqx.field(converter=jnp.asarray)

    def __check_init__(self):
        check_shape("rotations", self.rotations, (None, None, 4), what="(frames, joints, 4)")
        f, j = self.rotations.shape[:2]
        check_shape("translations", self.translations, (f, j, 3), what=f"(frames, joints, 3) = ({f}, {j}, 3)")
        check_shape("frame_time", self.frame_time, (), what="() (a scalar)")

    @property
    def num_frames(self) -> int:
        return self.rotations.shape[0]

    @property
    def num_joints(self) -> int:
        return self.rotations.shape[1]

    @property
    def fps(self) -> float:
        return float(1.0 / self.frame_time)

    @property
    def root_translations(self) -> Float[Array, "frames 3"]:
        return self.translations[:, 0]

    def check_finite(self, name: str = "motion") -> None:
        """Raise :class:`JaxanimError` when a frame holds NaN or inf (naming the frames) or ``frame_time``
        is not a positive finite number: for the algorithms that would otherwise report success on NaN."""
        def finite(a):  # [T] every value of the frame finite (also for a clip of no frames)
            a = np.asarray(a)
            return np.all(np.isfinite(a.reshape(a.shape[0], int(np.prod(a.shape[1:])))), axis=1)

        bad = ~(finite(self.rotations) & finite(self.translations))
        if bad.any():
            frames = np.flatnonzero(bad)
            raise JaxanimError(f"{name}: the clip has NaN or inf values in {len(frames)} frame(s), the first "
                               f"{frames[:5].tolist()}; fix or cut those frames first")
        self.check_frame_time(name)

    def check_frame_time(self, name: str = "motion") -> None:
        """Raise :class:`JaxanimError` unless ``frame_time`` is a positive finite number of seconds, when it
        is concrete (a traced one, under ``jit`` or ``vmap``, is the caller's to check): the check of every
        function that takes a clip and uses its frame time (a negative or zero one gave negative
        velocities, an empty resample or a clip written with a nonsense rate, without a word)."""
        if isinstance(self.frame_time, jax.core.Tracer):
            return
        ft = np.asarray(self.frame_time, dtype=np.float64)
        if ft.shape != () or not np.isfinite(ft) or ft <= 0:
            raise JaxanimError(f"{name}: frame_time must be a positive number of seconds, got {ft}")

    def check_skeleton(self, skeleton: Skeleton, name: str = "motion") -> None:
        """Raise :class:`JaxanimError` unless this clip has one column per joint of ``skeleton``."""
        if self.num_joints != skeleton.num_joints:
            raise JaxanimError(
                f"{name}: expected {skeleton.num_joints} joints (the skeleton's), got {self.num_joints}"
            )


def rest_motion(skeleton: Skeleton, num_frames: int = 1, frame_time: float = 1 / 30) -> Motion:
    """A clip holding the rest pose (identity rotations, OFFSET translations) for ``num_frames``."""
    rot = jnp.broadcast_to(skeleton.rest_rotations(), (num_frames, skeleton.num_joints, 4))
    trans = jnp.broadcast_to(skeleton.offsets, (num_frames, skeleton.num_joints, 3))
    return Motion(rot, trans, jnp.asarray(frame_time, dtype=skeleton.offsets.dtype))
