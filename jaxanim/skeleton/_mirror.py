"""Mirroring a clip: the left/right joint pairs of a skeleton (from the names, with overrides) and
the clip reflected through a plane normal to an axis, its partners' rotations and positions swapped.

Everything here solves one clip; batch with :func:`jax.vmap`. The pairs and the axis are static.
"""

from __future__ import annotations

import re
from collections.abc import Mapping

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._errors import JaxanimError
from ._processing import _check_motion, _is_int
from ._skeleton import Motion, Skeleton

_AXES = {"x": 0, "y": 1, "z": 2}
_MIRROR_RTOL = 1e-3  # default: offsets of partners mirror each other within this x the largest offset

_WORD = re.compile(r"left|right", re.IGNORECASE)
# a one-letter side: at the start before a separator or a capital (l_hand, LHipJoint, lShoulder),
# or at the end after a separator or a small letter (Hand_L, hand.r, HandL)
_PREFIX = re.compile(r"^(?P<pre>(?:.*[:|])?)(?P<side>[LlRr])(?=[_.\- ]|[A-Z])")
_SUFFIX = re.compile(r"(?:(?<=[_.\- ])|(?<=[a-z]))(?P<side>[LlRr])$")


def _swap_case(word: str, like: str) -> str:
    if like.isupper():
        return word.upper()
    if like[0].isupper():
        return word.capitalize()
    return word.lower()


def _side_partner(name: str) -> str | None:
    """The name with its side marker swapped, or ``None`` for a name without one."""
    if _WORD.search(name):
        return _WORD.sub(lambda m: _swap_case("right" if m.group(0).lower() == "left" else "left", m.group(0)), name)
    swap = {"L": "R", "R": "L", "l": "r", "r": "l"}
    m = _PREFIX.match(name)
    if m:
        i = m.start("side")
        return name[:i] + swap[name[i]] + name[i + 1:]
    m = _SUFFIX.search(name)
    if m:
        i = m.start("side")
        return name[:i] + swap[name[i]] + name[i + 1:]
    return None


def _lenient_partner(name: str, index: dict, lower: dict, default: int) -> int:
    swap = {"L": "R", "R": "L", "l": "r", "r": "l"}
    for k in (0, len(name) - 1):
        if len(name) > 1 and name[k] in swap:
            other = name[:k] + swap[name[k]] + name[k + 1:]
            if other in index:
                return index[other]
            if len(lower.get(other.lower(), [])) == 1:
                return lower[other.lower()][0]
    return default


def mirror_pairs(skeleton: Skeleton, overrides: Mapping[str, str] | None = None) -> tuple[int, ...]:
    """Each joint's left / right partner, found by name (itself for a joint on the center line).

    A side is marked by the words ``Left`` / ``Right`` anywhere in the name (``LeftArm``,
    ``mixamorig:RightHand``, ``arm_left``; any case), else by one letter ``L`` / ``R`` at the start
    before a separator or a capital (``LHipJoint``, ``lShoulder``, ``l_hand``) or at the end after a
    separator or a small letter (``Hand_L``, ``hand.r``, ``HandR``). The partner's name swaps the
    marker, keeping its case (matched case-insensitively when no exact match exists). A name with
    none of these pairs by its first or last letter only when the swapped name exists (``lhand`` /
    ``rhand``; ``Leg`` stays centered).

    Args:
        skeleton: the skeleton.
        overrides: ``{name: partner name}`` for names the rules miss or get wrong (each pair is
            applied both ways; a name mapped to itself is centered).

    Returns:
        ``pairs``: a tuple of joint indices, ``pairs[j]`` the partner of joint ``j``; an involution
        that maps the tree onto itself (``parents[pairs[j]] == pairs[parents[j]]``).

    Raises:
        JaxanimError: a sided joint without a partner (the names are listed), an unknown name in
            ``overrides``, or partners whose parents are not partners.
    """
    names = skeleton.names
    index = {n: i for i, n in enumerate(names)}
    lower: dict[str, list[int]] = {}
    for i, n in enumerate(names):
        lower.setdefault(n.lower(), []).append(i)
    fixed: dict[int, int] = {}
    for k, v in dict(overrides or {}).items():
        for x in (k, v):
            if x not in index:
                raise JaxanimError(f"overrides: unknown joint {x!r}; valid joints: {list(names)}")
        i, j = index[k], index[v]
        for x, y in ((i, j), (j, i)):
            if fixed.get(x, y) != y:
                raise JaxanimError(f"overrides: joint {names[x]!r} is given two partners: "
                                   f"{names[fixed[x]]!r} and {names[y]!r}")
            fixed[x] = y
    pairs, missing = [], []
    for i, n in enumerate(names):
        if i in fixed:
            pairs.append(fixed[i])
            continue
        partner = _side_partner(n)
        if partner is None:  # a one-letter side without a separator (lhand / rhand): only if both exist
            pairs.append(_lenient_partner(n, index, lower, i))
        elif partner in index:
            pairs.append(index[partner])
        elif len(lower.get(partner.lower(), [])) == 1:
            pairs.append(lower[partner.lower()][0])
        else:
            missing.append(f"{n!r} (no {partner!r})")
            pairs.append(i)
    if missing:
        raise JaxanimError("mirror_pairs: joints on one side without a partner on the other: "
                           + ", ".join(missing)
                           + "; pass overrides={name: partner} (a name mapped to itself is centered)")
    bad = [f"{names[i]!r} -> {names[p]!r} -> {names[pairs[p]]!r}" for i, p in enumerate(pairs) if pairs[p] != i]
    if bad:
        raise JaxanimError("mirror_pairs: partners must pair up both ways, got " + ", ".join(bad))
    parents = skeleton.parents
    bad = [f"{names[i]!r} <-> {names[p]!r}" for i, p in enumerate(pairs) if i <= p and (
        (parents[i] < 0) != (parents[p] < 0) or (parents[i] >= 0 and pairs[parents[i]] != parents[p]))]
    if bad:
        raise JaxanimError("mirror_pairs: partners whose parents are not partners (the tree is not "
                           "left-right symmetric under these pairs): " + ", ".join(bad))
    return tuple(pairs)


def _axis(axis) -> int:
    if isinstance(axis, str) and axis.lower() in _AXES:
        return _AXES[axis.lower()]
    if _is_int(axis) and 0 <= int(axis) <= 2:
        return int(axis)
    raise JaxanimError(f"axis: expected 'x', 'y' or 'z' (the normal of the mirror plane), got {axis!r}")


def _end_site_pairs(skeleton: Skeleton, pairs: tuple[int, ...]) -> list[tuple[int, int]]:
    """End Site ``e`` of joint ``j`` pairs with the End Site of the same rank on ``pairs[j]``."""
    by_joint: dict[int, list[int]] = {}
    for e, p in enumerate(skeleton.end_site_parents):
        by_joint.setdefault(p, []).append(e)
    out = []
    for j, es in by_joint.items():
        other = by_joint.get(pairs[j], [])
        if len(other) != len(es):
            raise JaxanimError(
                f"skeleton: joint {skeleton.names[j]!r} has {len(es)} End Site(s) but its partner "
                f"{skeleton.names[pairs[j]]!r} has {len(other)}; the skeleton is not mirror-symmetric"
            )
        out += list(zip(es, other))
    return out


def _check_symmetric(skeleton: Skeleton, pairs: tuple[int, ...], ax: int, rtol: float) -> None:
    off = skeleton.offsets
    if isinstance(off, jax.core.Tracer) or isinstance(skeleton.end_site_offsets, jax.core.Tracer):
        raise JaxanimError("skeleton: check=True needs concrete offsets (close over the skeleton under jit, "
                           "or pass check=False)")
    off = np.asarray(off, np.float64)
    es = np.asarray(skeleton.end_site_offsets, np.float64)
    sign = np.ones(3)
    sign[ax] = -1.0
    scale = max(float(np.linalg.norm(off[1:], axis=-1).max(initial=0.0)),
                float(np.linalg.norm(es, axis=-1).max(initial=0.0)), 1e-300)
    tol = rtol * scale
    bad = []
    for j, p in enumerate(pairs):
        if j == 0:
            continue  # the root's OFFSET is its rest position: not part of the shape
        d = float(np.abs(off[j] - sign * off[p]).max())
        if d > tol:
            bad.append((d, f"{skeleton.names[j]!r} {off[j].tolist()} vs mirrored {skeleton.names[p]!r} "
                           f"{(sign * off[p]).tolist()}"))
    for e, f in _end_site_pairs(skeleton, pairs):
        d = float(np.abs(es[e] - sign * es[f]).max())
        if d > tol:
            name = skeleton.end_site_names
            bad.append((d, f"{name[e]!r} {es[e].tolist()} vs mirrored {name[f]!r} {(sign * es[f]).tolist()}"))
    if bad:
        bad.sort(key=lambda x: -x[0])
        raise JaxanimError(
            f"skeleton: the offsets of {len(bad)} joint(s) / End Site(s) do not mirror their partners' across "
            f"the {'xyz'[ax]} plane within {tol:.3g} ({rtol:g} x the largest offset), so the mirrored clip "
            "would not fit this skeleton; worst: " + "; ".join(s for _, s in bad[:3])
            + "; pass check=False to mirror anyway"
        )


def mirror(
    motion: Motion,
    skeleton: Skeleton,
    *,
    axis="x",
    pairs: tuple[int, ...] | None = None,
    check: bool = True,
    rtol: float = _MIRROR_RTOL,
) -> Motion:
    """Mirror a clip across the plane through the origin normal to ``axis`` (left <-> right).

    With ``M`` the reflection (``-1`` on ``axis``): partners swap (``pairs``), each rotation becomes
    ``M R M`` (a proper rotation: for ``axis = x`` the quaternion ``(w, x, y, z) -> (w, x, -y, -z)``;
    in general the component along ``axis`` is kept and the other two negated), and position-channel
    translations (the root position) become ``M t``. Joints without position channels keep their
    own translation (the OFFSET), which equals ``M t`` of the partner's on a mirror-symmetric
    skeleton; then FK of the mirrored clip is the reflection of the original's, joint by partner.
    Mirroring twice gives the clip back.

    Args:
        motion: the clip on ``skeleton``.
        skeleton: its skeleton (names for :func:`mirror_pairs`, offsets for the symmetry check).
        axis: the plane's normal, ``"x"`` (the usual left / right axis of BVH skeletons), ``"y"``
            or ``"z"``.
        pairs: the partner of every joint (default: :func:`mirror_pairs` of ``skeleton``).
        check: raise unless the skeleton's offsets of partners mirror each other (the mirrored clip
            is only valid on such a skeleton). Needs concrete offsets.
        rtol: the check's tolerance, relative to the largest offset.

    Returns:
        The mirrored :class:`Motion`.

    Raises:
        JaxanimError: a clip not on the skeleton, a bad ``axis`` or ``pairs``, a skeleton that is not
            mirror-symmetric (with ``check``), or names without partners (from :func:`mirror_pairs`).
    """
    _check_motion("motion", motion)
    motion.check_skeleton(skeleton, "motion")
    ax = _axis(axis)
    J = skeleton.num_joints
    if pairs is None:
        pairs = mirror_pairs(skeleton)
    else:
        if not (isinstance(pairs, (tuple, list)) and len(pairs) == J and all(_is_int(p) for p in pairs)):
            raise JaxanimError(f"pairs: expected {J} joint indices (one per joint), got {pairs!r}")
        pairs = tuple(int(p) for p in pairs)
        if sorted(pairs) != list(range(J)) or any(pairs[p] != i for i, p in enumerate(pairs)):
            raise JaxanimError(f"pairs: expected a permutation that pairs joints both ways "
                               f"(pairs[pairs[j]] == j), got {pairs}")
    if check:
        _check_symmetric(skeleton, pairs, ax, rtol)
    return _mirror(motion, pairs, ax, tuple(skeleton.has_position_channels))


@eqx.filter_jit
def _mirror(motion: Motion, pairs: tuple, ax: int, has_position: tuple) -> Motion:
    dtype = motion.rotations.dtype
    perm = np.asarray(pairs, dtype=np.int32)
    q_sign = np.full(4, -1.0)
    q_sign[0] = 1.0
    q_sign[1 + ax] = 1.0
    t_sign = np.ones(3)
    t_sign[ax] = -1.0
    q = motion.rotations[:, perm] * jnp.asarray(q_sign, dtype)[None, None]
    has_pos = np.asarray(has_position)[:, None]  # [J, 1]
    t_swapped = motion.translations[:, perm] * jnp.asarray(t_sign, dtype)[None, None]
    t = jnp.where(jnp.asarray(has_pos)[None], t_swapped, motion.translations)
    return Motion(q, t, motion.frame_time)
