"""The motion-matching database: the normalised features of every frame of one or many clips (and
their mirror images), which rows may be searched, where each row came from, and the poses that
playback needs."""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._errors import JaxanimError
from .._types import Array, Bool, Float, Int
from ..skeleton._skeleton import Motion, Skeleton
from ._features import (
    FeatureLayout,
    FeatureOptions,
    clip_features,
    contact_thresholds,
    make_layout,
)
from ..skeleton._mirror import mirror as mirror_motion

__all__ = ["MatchingDatabase", "build_database", "normalize_features"]


class MatchingDatabase(eqx.Module):
    """Frames of one or many clips on one skeleton, ready to search and play.

    A row is one frame. Rows whose future trajectory window (the longest trajectory time) runs past the
    end of their clip are kept for playback but are not searchable: the search never lands on them,
    so every searched frame can play on for the whole window.

    Attributes:
        features: ``[rows, features]`` normalised, weighted features: ``(x - mean) * scale``.
        squared_norms: ``[rows]`` ``|features|^2``; ``+inf`` for rows that are not searchable (the
            search's mask).
        mean: ``[features]`` mean of the raw features over the searchable rows.
        scale: ``[features]`` weight / standard deviation of each dimension's block.
        searchable: ``[rows]`` whether the search may return the row.
        clip: ``[rows]`` index of the clip in the list given to :func:`build_database` (mirror
            images follow the originals: clip ``c``'s mirror image is clip ``c + clips``).
        frame: ``[rows]`` frame index within the clip.
        last: ``[rows]`` whether the row is the last frame of its clip (playback cannot advance).
        rotations: ``[rows, joints, 4]`` local joint rotations; the root's relative to the frame's
            facing frame.
        translations: ``[rows, joints, 3]`` local translations; the root's in the facing frame
            (``(0, height, 0)``).
        angular_velocities: ``[rows, joints, 3]`` local angular velocities (rad/s).
        root_velocity: ``[rows, 3]`` velocity of the root translation in the facing frame.
        step_position: ``[rows, 3]`` displacement of the facing origin from the previous frame, in the
            previous frame's facing frame (a clip's first row repeats its second's).
        step_yaw: ``[rows]`` change of the facing yaw from the previous frame (radians).
        frame_time: seconds per frame (all clips share it).
        mean_speed: mean ground speed of the facing origin over the searchable rows (file units/s).
        contact_height, contact_speed: the foot-contact thresholds used (file units, per second;
            the height above ``ground``, the lowest foot height in the database).
        skeleton: the clips' skeleton.
        layout: the feature layout (static).
    """

    features: Float[Array, "rows features"]
    squared_norms: Float[Array, " rows"]
    mean: Float[Array, " features"]
    scale: Float[Array, " features"]
    searchable: Bool[Array, " rows"]
    clip: Int[Array, " rows"]
    frame: Int[Array, " rows"]
    last: Bool[Array, " rows"]
    rotations: Float[Array, "rows joints 4"]
    translations: Float[Array, "rows joints 3"]
    angular_velocities: Float[Array, "rows joints 3"]
    root_velocity: Float[Array, "rows 3"]
    step_position: Float[Array, "rows 3"]
    step_yaw: Float[Array, " rows"]
    frame_time: Float[Array, ""]
    mean_speed: Float[Array, ""]
    contact_height: Float[Array, ""]
    contact_speed: Float[Array, ""]
    ground: Float[Array, ""]
    skeleton: Skeleton
    layout: FeatureLayout = eqx.field(static=True)

    @property
    def num_rows(self) -> int:
        return self.features.shape[0]

    @property
    def num_features(self) -> int:
        return self.features.shape[1]


def normalize_features(db: MatchingDatabase, raw: Float[Array, "*batch features"]) -> Float[Array, "*batch features"]:
    """Raw features (the layout of ``db.layout``) to the database's normalised, weighted space."""
    raw = jnp.asarray(raw)
    shape = (1,) * (raw.ndim - 1) + (-1,)
    return (raw - db.mean.reshape(shape)) * db.scale.reshape(shape)


def _same_skeleton(a: Skeleton, b: Skeleton) -> bool:
    if a.names != b.names or a.parents != b.parents:
        return False
    return bool(np.allclose(np.asarray(a.offsets), np.asarray(b.offsets), rtol=1e-6, atol=1e-9))


def build_database(
    clips: Sequence[Motion],
    skeleton: Skeleton,
    *,
    mirror: bool = False,
    mirror_check: bool = True,
    options: FeatureOptions | None = None,
    skeletons: Sequence[Skeleton] | None = None,
    sources: Sequence[str] | None = None,
    dtype=None,
) -> MatchingDatabase:
    """Build a motion-matching database from clips on one skeleton (host-side, once).

    Each block of the feature vector is normalised over the searchable rows: the dimension's mean is
    subtracted and the block is divided by the mean standard deviation of its dimensions (1 where
    that is 0), then multiplied by its weight (Holden's normalisation). Rows within the longest
    trajectory time of a clip's end are **excluded** from the search (not clamped).

    Args:
        clips: one or more :class:`Motion` on ``skeleton``, all at the same frame time.
        skeleton: their skeleton.
        mirror: also add every clip's mirror image (across ``x``, left and right swapped:
            :func:`jaxanim.skeleton.mirror`).
        mirror_check: refuse a skeleton whose left and right offsets do not mirror each other (the
            mirror images would not fit it); ``False`` mirrors anyway (the CMU skeletons are nearly
            symmetric).
        options: :class:`FeatureOptions` (default ``FeatureOptions()``).
        skeletons: optionally each clip's own skeleton (e.g. as read from its file): a clip whose
            skeleton differs from ``skeleton`` is an error naming it.
        sources: a label per clip for messages (default ``"clip <i>"``).
        dtype: the arrays' dtype (default the clips').

    Returns:
        A :class:`MatchingDatabase`.

    Raises:
        JaxanimError: no clips; a clip with the wrong joint count, a different skeleton or frame
            time, or a frame time that is not a positive number (naming the clip); an unknown foot or hand joint; no searchable frame (every clip
            shorter than the trajectory window).
    """
    options = FeatureOptions() if options is None else options
    if isinstance(clips, Motion):
        raise JaxanimError("clips: expected a sequence of Motion, got one Motion (pass [motion])")
    clips = list(clips)
    if not clips:
        raise JaxanimError("clips: expected at least one clip")
    for i, c in enumerate(clips):
        if not isinstance(c, Motion):
            raise JaxanimError(f"clips[{i}]: expected a jaxanim Motion, got {type(c).__name__}")
    labels = list(sources) if sources is not None else [f"clip {i}" for i in range(len(clips))]
    if len(labels) != len(clips):
        raise JaxanimError(f"sources: expected {len(clips)} labels (one per clip), got {len(labels)}")
    if skeletons is not None:
        if len(skeletons) != len(clips):
            raise JaxanimError(f"skeletons: expected {len(clips)} skeletons (one per clip), got {len(skeletons)}")
        for i, s in enumerate(skeletons):
            if not _same_skeleton(s, skeleton):
                raise JaxanimError(f"{labels[i]}: its skeleton differs from the database's (that of {labels[0]}): "
                                   "every clip must have the same joints, parents and offsets")
    dt = float(clips[0].frame_time)
    for i, m in enumerate(clips):
        if not isinstance(m, Motion):
            raise JaxanimError(f"{labels[i]}: expected a Motion, got {type(m).__name__}")
        m.check_skeleton(skeleton, labels[i])
        m.check_frame_time(labels[i])
        if abs(float(m.frame_time) - dt) > 1e-6 * dt:
            raise JaxanimError(f"{labels[i]}: frame time {float(m.frame_time):g} s differs from {labels[0]}'s {dt:g} s "
                               "(resample the clips to one rate)")
    dtype = dtype or clips[0].rotations.dtype
    layout = make_layout(skeleton, dt, options)
    if mirror:
        clips = clips + [mirror_motion(m, skeleton, check=mirror_check) for m in clips]
    if all(m.num_frames <= max(layout.trajectory_frames) for m in clips):
        raise JaxanimError(f"clips: no frame can be searched: every clip is shorter than the trajectory window "
                           f"({max(layout.trajectory_times):g} s = {max(layout.trajectory_frames)} frames + 1)")
    per = [clip_features(skeleton, m, layout) for m in clips]
    cat = {k: np.concatenate([getattr(c, k) for c in per], axis=0) for k in (
        "features", "searchable", "rotations", "translations", "angular_velocities", "root_velocity",
        "step_position", "step_yaw", "foot_height", "foot_speed", "ground_speed")}
    searchable = cat["searchable"]
    if not searchable.any():
        raise JaxanimError(f"clips: no frame can be searched: every clip is shorter than the trajectory window "
                           f"({max(layout.trajectory_times):g} s = {max(layout.trajectory_frames)} frames + 1)")
    # foot contacts, with database-wide thresholds
    ground = float(cat["foot_height"].min())
    h, v = contact_thresholds(skeleton, layout, options)
    contacts = ((cat["foot_height"] - ground < h) & (cat["foot_speed"] < v)).astype(np.float64)
    raw = cat["features"]
    raw[:, layout.slice("foot_contacts")] = contacts
    # normalisation over the searchable rows, one deviation per block
    mean = raw[searchable].mean(axis=0)
    std = raw[searchable].std(axis=0)
    w = options.weights
    scale = np.zeros(raw.shape[1])
    for name, _ in layout.blocks:
        s = layout.slice(name)
        sd = float(std[s].mean())
        scale[s] = float(getattr(w, name)) / (sd if sd > 1e-8 else 1.0)
    feats = (raw - mean) * scale
    sq = np.where(searchable, np.sum(feats * feats, axis=1), np.inf)
    clip_idx = np.concatenate([np.full(len(c.searchable), i) for i, c in enumerate(per)])
    frame_idx = np.concatenate([np.arange(len(c.searchable)) for c in per])
    last = np.concatenate([np.arange(len(c.searchable)) == len(c.searchable) - 1 for c in per])
    f = lambda x: jnp.asarray(x, dtype=dtype)  # noqa: E731
    return MatchingDatabase(
        features=f(feats), squared_norms=f(sq), mean=f(mean), scale=f(scale), searchable=jnp.asarray(searchable),
        clip=jnp.asarray(clip_idx, jnp.int32), frame=jnp.asarray(frame_idx, jnp.int32), last=jnp.asarray(last),
        rotations=f(cat["rotations"]), translations=f(cat["translations"]),
        angular_velocities=f(cat["angular_velocities"]), root_velocity=f(cat["root_velocity"]),
        step_position=f(cat["step_position"]), step_yaw=f(cat["step_yaw"]), frame_time=f(dt),
        mean_speed=f(cat["ground_speed"][searchable].mean()), contact_height=f(h), contact_speed=f(v), ground=f(ground),
        skeleton=skeleton, layout=layout)
