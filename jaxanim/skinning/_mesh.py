"""Meshes and skin weights as Modules, their checks, and a procedural capsule skin for any skeleton.

A :class:`Mesh` is ``vertices [V, 3]`` and triangles ``faces [T, 3]`` (0-based int32 indices). A
:class:`SkinWeights` gives every vertex ``K`` joints (indices in the skeleton's joint order) and
their weights. Both check their shapes when built, and their values (face indices in range; joint
indices in range, weights non-negative and summing to 1: :func:`check_weights`) whenever the arrays
are concrete, that is outside ``jit`` / ``vmap`` / ``grad``; traced values are the caller's
responsibility.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._errors import JaxanimError, check_shape
from .._types import Array, Float, Int
from ..skeleton._skeleton import Skeleton
from ._bind import _bind_rt


def _is_traced(*xs) -> bool:
    return any(isinstance(x, jax.core.Tracer) for x in xs)


def _as_float_array(name: str, x) -> Array:
    """``x`` as a floating jax array (integers become the default float); complex/bool/object refused."""
    try:
        arr = jnp.asarray(x)
    except (TypeError, ValueError) as exc:
        raise JaxanimError(f"{name}: expected a real floating-point array, got {type(x).__name__}") from exc
    if jnp.issubdtype(arr.dtype, jnp.floating):
        return arr
    if jnp.issubdtype(arr.dtype, jnp.integer):
        return arr.astype(jnp.result_type(float))
    raise JaxanimError(f"{name}: expected a real floating-point array, got dtype {arr.dtype}")


def _as_index_array(name: str, x) -> Array:
    """``x`` as an int32 jax array; a floating or boolean array is refused (no silent truncation)."""
    try:
        arr = jnp.asarray(x)
    except (TypeError, ValueError) as exc:
        raise JaxanimError(f"{name}: expected an integer array, got {type(x).__name__}") from exc
    if arr.size and not jnp.issubdtype(arr.dtype, jnp.integer):
        raise JaxanimError(f"{name}: expected an integer array of indices, got dtype {arr.dtype}")
    if not _is_traced(arr):
        a = np.asarray(arr)
        if a.size and (a.max() > np.iinfo(np.int32).max or a.min() < np.iinfo(np.int32).min):
            raise JaxanimError(f"{name}: indices do not fit in int32 (range {a.min()} to {a.max()})")
    return arr.astype(jnp.int32)


class Mesh(eqx.Module):
    """A triangle mesh.

    Attributes:
        vertices: ``[V, 3]`` vertex positions (file units), float.
        faces: ``[T, 3]`` int32 vertex indices of each triangle, 0-based, counter-clockwise seen
            from outside (``None``: no faces, a point cloud).

    Raises:
        JaxanimError: on a wrong shape or dtype, or (for concrete arrays) a face index outside
            ``[0, V)``, naming the face.
    """

    vertices: Float[Array, "V 3"]
    faces: Int[Array, "T 3"]

    def __init__(self, vertices, faces=None):
        vertices = _as_float_array("vertices", vertices)
        check_shape("vertices", vertices, (None, 3), what="(V, 3)")
        faces = _as_index_array("faces", np.zeros((0, 3), np.int32) if faces is None else faces)
        check_shape("faces", faces, (None, 3), what="(T, 3)")
        if not _is_traced(faces) and faces.shape[0]:
            f = np.asarray(faces)
            bad = np.nonzero((f < 0).any(axis=1) | (f >= vertices.shape[0]).any(axis=1))[0]
            if bad.size:
                t = int(bad[0])
                raise JaxanimError(
                    f"faces: face {t} has vertex indices {f[t].tolist()}, outside [0, {vertices.shape[0]}) "
                    f"(the mesh has {vertices.shape[0]} vertices; {bad.size} bad face(s))"
                )
        self.vertices = vertices
        self.faces = faces

    @property
    def num_vertices(self) -> int:
        return self.vertices.shape[0]

    @property
    def num_faces(self) -> int:
        return self.faces.shape[0]


class SkinWeights(eqx.Module):
    """``K`` influences per vertex: joint indices and their weights.

    Attributes:
        joints: ``[V, K]`` int32 joint indices in the skeleton's joint order.
        weights: ``[V, K]`` non-negative weights; each row sums to 1 (checked by
            :func:`check_weights` and :func:`~jaxanim.skinning.skin`, not here).

    Raises:
        JaxanimError: on a wrong shape or dtype (``joints`` must be an integer array).
    """

    joints: Int[Array, "V K"]
    weights: Float[Array, "V K"]

    def __init__(self, joints, weights):
        joints = _as_index_array("joints", joints)
        check_shape("joints", joints, (None, None), what="(V, K)")
        weights = _as_float_array("weights", weights)
        check_shape("weights", weights, joints.shape, what=f"(V, K) = {tuple(joints.shape)} (the joints' shape)")
        self.joints = joints
        self.weights = weights

    @property
    def num_vertices(self) -> int:
        return self.joints.shape[0]

    @property
    def k(self) -> int:
        return self.joints.shape[1]


def _sum_atol(dtype) -> float:
    return 1e-6 if jnp.finfo(dtype).bits >= 64 else 1e-4


def check_weights(
    skeleton: Skeleton,
    weights: SkinWeights,
    num_vertices: int | None = None,
    *,
    normalize: bool = False,
    atol: float | None = None,
) -> SkinWeights:
    """Check skin weights against a skeleton (and a vertex count); optionally normalise them.

    Shapes are always checked; values (joint indices in ``[0, joints)``, finite non-negative
    weights, rows summing to 1 within ``atol``) only when the arrays are concrete (outside
    ``jit``, ``vmap`` and ``grad``). With ``normalize=True`` each row is divided by its sum instead
    of being required to sum to 1 (traced weights too); a row whose weights are all zero is still an
    error.

    Args:
        skeleton: the skeleton the joint indices refer to.
        weights: the :class:`SkinWeights`.
        num_vertices: the mesh's vertex count ``V`` (checked against the rows), or ``None``.
        normalize: divide each row by its sum.
        atol: tolerance on each row's sum (default ``1e-6`` in float64, ``1e-4`` in float32).

    Returns:
        The weights (normalised if asked; a new Module, the input is not modified).

    Raises:
        JaxanimError: naming the problem and the first vertex at fault: rows that do not match the
            vertices, a joint index out of range, a negative or non-finite weight, a row not
            summing to 1 (with the hint ``normalize=True``), a row of zeros.
    """
    if not isinstance(skeleton, Skeleton):
        raise JaxanimError(f"skeleton: expected a jaxanim.Skeleton, got {type(skeleton).__name__}")
    if not isinstance(weights, SkinWeights):
        raise JaxanimError(f"weights: expected a jaxanim.skinning.SkinWeights, got {type(weights).__name__}")
    V, K = weights.joints.shape
    J = skeleton.num_joints
    if num_vertices is not None and V != num_vertices:
        raise JaxanimError(
            f"weights: expected one row per vertex, (V, K) = ({num_vertices}, K), got {V} rows "
            f"(shape {tuple(weights.joints.shape)}): the weights do not match the mesh's {num_vertices} vertices"
        )
    if K == 0:
        raise JaxanimError(f"weights: expected at least one influence per vertex (K >= 1), got shape ({V}, 0)")
    w = weights.weights
    if not _is_traced(weights.joints):
        j = np.asarray(weights.joints)
        bad = np.nonzero(((j < 0) | (j >= J)).any(axis=1))[0]
        if bad.size:
            v = int(bad[0])
            slot = int(np.nonzero((j[v] < 0) | (j[v] >= J))[0][0])
            raise JaxanimError(
                f"weights.joints: vertex {v} has joint index {int(j[v, slot])} (slot {slot}), out of range for "
                f"a skeleton of {J} joints (valid: 0 to {J - 1}); {bad.size} vertex(es) affected"
            )
    if not _is_traced(w):
        a = np.asarray(w, dtype=np.float64)
        bad = np.nonzero(~np.isfinite(a).all(axis=1))[0]
        if bad.size:
            v = int(bad[0])
            raise JaxanimError(f"weights.weights: vertex {v} has a non-finite weight: {a[v].tolist()}")
        bad = np.nonzero((a < 0).any(axis=1))[0]
        if bad.size:
            v = int(bad[0])
            slot = int(np.argmin(a[v]))
            raise JaxanimError(
                f"weights.weights: vertex {v} has a negative weight {a[v, slot]:g} (slot {slot}); weights must be "
                f">= 0; {bad.size} vertex(es) affected"
            )
        s = a.sum(axis=1)
        bad = np.nonzero(s <= 0)[0]
        if bad.size:
            raise JaxanimError(
                f"weights.weights: vertex {int(bad[0])} has all its weights zero: it cannot be skinned "
                f"(or normalised); {bad.size} vertex(es) affected"
            )
        if not normalize:
            tol = _sum_atol(w.dtype) if atol is None else float(atol)
            bad = np.nonzero(np.abs(s - 1.0) > tol)[0]
            if bad.size:
                v = int(bad[0])
                raise JaxanimError(
                    f"weights.weights: vertex {v}'s weights sum to {s[v]:.9g}, expected 1 (tolerance {tol:g}); "
                    f"{bad.size} vertex(es) affected; pass normalize=True to divide each row by its sum"
                )
    if normalize:
        return SkinWeights(weights.joints, w / jnp.sum(w, axis=1, keepdims=True))
    return weights


# ------------------------------------------------------------------------------------------------
# The procedural capsule skin
# ------------------------------------------------------------------------------------------------


def rest_sites(skeleton: Skeleton, bind=None) -> tuple[np.ndarray, np.ndarray]:
    """Host copies of the bind-pose joint positions ``[J, 3]`` and End Site positions ``[E, 3]``."""
    R, p = _bind_rt(skeleton, bind)
    if _is_traced(R, p):
        raise JaxanimError("bind: the bind pose must be concrete here (this runs on the host), got a traced array")
    R, p = np.asarray(R, np.float64), np.asarray(p, np.float64)
    es_par = list(skeleton.end_site_parents)
    es = np.asarray(skeleton.end_site_offsets, np.float64)
    e = p[es_par] + np.einsum("eab,eb->ea", R[es_par], es) if es_par else np.zeros((0, 3))
    return p, e


def bone_segments(skeleton: Skeleton, bind=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The bones as segments ``(a [S, 3], b [S, 3], owner [S])`` in the bind pose.

    The bone from joint ``p`` to its child joint ``j`` moves with ``p`` (it lies in ``p``'s
    frame), so it is owned by ``p``; the bone to an End Site by the End Site's joint. A joint that
    owns no bone of non-zero length (a leaf without an End Site) gets a point segment at its
    position, so every joint owns at least one segment.
    """
    p, e = rest_sites(skeleton, bind)
    eps = 1e-9 * _size(p, e)
    a, b, owner = [], [], []
    for j, par in enumerate(skeleton.parents):
        if par >= 0 and np.linalg.norm(p[j] - p[par]) > eps:
            a.append(p[par]), b.append(p[j]), owner.append(par)
    for k, par in enumerate(skeleton.end_site_parents):
        if np.linalg.norm(e[k] - p[par]) > eps:
            a.append(p[par]), b.append(e[k]), owner.append(par)
    for j in sorted(set(range(skeleton.num_joints)) - set(owner)):
        a.append(p[j]), b.append(p[j]), owner.append(j)
    return np.asarray(a, np.float64).reshape(-1, 3), np.asarray(b, np.float64).reshape(-1, 3), np.asarray(owner)


def skeleton_size(skeleton: Skeleton, bind=None) -> float:
    """The largest extent of the bind pose's bounding box (joints and End Sites), file units."""
    return _size(*rest_sites(skeleton, bind))


def _size(p: np.ndarray, e: np.ndarray) -> float:
    pts = np.concatenate([p, e], axis=0)
    size = float((pts.max(axis=0) - pts.min(axis=0)).max())
    return size if size > 0 else 1.0


def _capsule(a: np.ndarray, b: np.ndarray, r: float, sides: int, rings: int, cap_rings: int, seg_eps: float):
    """Vertices and faces (0-based, outward counter-clockwise) of one capsule from ``a`` to ``b``."""
    d = b - a
    length = float(np.linalg.norm(d))
    u = d / length if length > seg_eps else np.array([0.0, 1.0, 0.0])
    if length <= seg_eps:
        length = 0.0
    helper = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(u, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)  # (e1, e2, u) right-handed
    # the profile: (axial position s along u from a, ring radius rho), pole to pole
    prof = []
    for i in range(1, cap_rings + 1):
        alpha = 0.5 * np.pi * i / cap_rings
        prof.append((-r * np.cos(alpha), r * np.sin(alpha)))
    if length > 0:
        prof += [(length * i / rings, r) for i in range(1, rings + 1)]
    for i in range(cap_rings - 1, 0, -1):
        alpha = 0.5 * np.pi * i / cap_rings
        prof.append((length + r * np.cos(alpha), r * np.sin(alpha)))
    phi = 2.0 * np.pi * np.arange(sides) / sides
    radial = np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2  # [sides, 3]
    verts = [a - r * u]
    verts += [a + s * u + rho * radial for s, rho in prof]
    verts.append(a + (length + r) * u)
    V = np.concatenate([np.atleast_2d(x) for x in verts], axis=0)
    n_rings = len(prof)
    top = 1 + n_rings * sides
    k = np.arange(sides)
    k1 = (k + 1) % sides
    faces = [np.stack([np.zeros(sides, int), 1 + k1, 1 + k], axis=1)]  # bottom fan
    for i in range(n_rings - 1):
        r0, r1 = 1 + i * sides, 1 + (i + 1) * sides
        faces.append(np.stack([r0 + k, r0 + k1, r1 + k1], axis=1))
        faces.append(np.stack([r0 + k, r1 + k1, r1 + k], axis=1))
    last = 1 + (n_rings - 1) * sides
    faces.append(np.stack([np.full(sides, top), last + k, last + k1], axis=1))  # top fan
    return V, np.concatenate(faces, axis=0)


def capsule_mesh(
    skeleton: Skeleton,
    radius: float | None = None,
    *,
    sides: int = 10,
    rings: int = 5,
    cap_rings: int = 2,
    bind=None,
    dtype=None,
) -> Mesh:
    """A procedural skin: one closed capsule (a tube with hemispherical caps) around every bone.

    Every bone of the bind pose (default: the rest pose), from a joint to each child joint and to
    each End Site, gets a capsule of radius ``radius``; a joint with no bone (a leaf without an End
    Site) gets a sphere. The capsules overlap at the joints and are not merged: skin it with
    :func:`heuristic_weights`. On the shipped 21-joint walk the defaults give 25 capsules, 2050
    vertices and 4000 triangles.

    Args:
        skeleton: any skeleton.
        radius: the capsules' radius (file units); default ``0.035 x`` the largest extent of the
            bind pose's bounding box (6 cm on the shipped 1.75 m walk).
        sides: vertices around each ring (>= 3).
        rings: ring intervals along each bone's cylinder (>= 1).
        cap_rings: rings in each hemispherical cap, the equator included (>= 1).
        bind: the bind pose, as for :func:`~jaxanim.skinning.skin` (default the rest pose).
        dtype: the vertices' dtype (default: the skeleton's offsets').

    Returns:
        A :class:`Mesh` in the bind pose.

    Raises:
        JaxanimError: if a size is out of range or the radius is not a positive number.
    """
    if not isinstance(skeleton, Skeleton):
        raise JaxanimError(f"skeleton: expected a jaxanim.Skeleton, got {type(skeleton).__name__}")
    for name, val, lo in (("sides", sides, 3), ("rings", rings, 1), ("cap_rings", cap_rings, 1)):
        if not isinstance(val, (int, np.integer)) or val < lo:
            raise JaxanimError(f"{name}: expected an integer >= {lo}, got {val!r}")
    size = skeleton_size(skeleton, bind)
    r = 0.035 * size if radius is None else float(radius)
    if not (np.isfinite(r) and r > 0):
        raise JaxanimError(f"radius: expected a positive finite number, got {radius!r}")
    a, b, _ = bone_segments(skeleton, bind)
    eps = 1e-9 * size
    all_v, all_f, n = [], [], 0
    for s in range(a.shape[0]):
        v, f = _capsule(a[s], b[s], r, int(sides), int(rings), int(cap_rings), eps)
        all_v.append(v)
        all_f.append(f + n)
        n += v.shape[0]
    dtype = skeleton.offsets.dtype if dtype is None else dtype
    return Mesh(jnp.asarray(np.concatenate(all_v), dtype), jnp.asarray(np.concatenate(all_f), jnp.int32))
