"""A robot drawn from its collision geometry (a retarget result's :class:`._retarget_clip.RobotGeometry`).

:func:`robot_shapes` places every geom in the world at one frame (numpy, no drawing), and
:class:`RobotArtist` draws them with matplotlib on a 3-D axes (Z up), in the robot's colour:

* a **capsule** as a thick segment between its end centres, with round caps, as wide as the capsule
  in the view (:func:`pixels_per_metre`), outlined in a darker shade; a **cylinder** the same with
  square caps; a **sphere** as a disc (a round marker) as wide as the sphere;
* a **box** as its six faces, shaded by a fixed light, with their edges;
* an **ellipsoid** as its three principal ellipses;
* a **mesh** as its surface points (its extreme vertices) as dots;
* a body with surface points but no geom (a **sole** that retargeting gave a foot without geometry) as
  the outline of its points (their convex hull in their plane).

The caller (:class:`._render._RetargetArtist`) draws the sticks between the body origins under them:
robots whose files keep little collision geometry (a G1 with its meshes stripped) still read as
figures.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ._retarget_clip import RobotGeometry

__all__ = ["RobotArtist", "RobotShapes", "pixels_per_metre", "quat_to_matrix", "robot_shapes"]

#: The 12 edges and 6 faces of a box whose corners are ``(x, y, z)`` in ``{-1, 1}^3``, ordered as
#: ``[[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]`` (corner ``4 x' + 2 y' + z'``).
_BOX_CORNERS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float64)
_BOX_FACES = np.array([[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]], np.int64)
_RING = 24  # segments per ellipse
_LIGHT = np.array([-0.4, -0.6, 1.0]) / np.linalg.norm([-0.4, -0.6, 1.0])
_DARK = 0.55  # the outline's shade of the robot's colour
_OUTLINE_POINTS = 1.2  # how much wider (points) the outline is than the capsule it frames
# collections start with a placeholder (matplotlib's add_collection3d cannot autoscale an empty one)
_ONE_SEGMENT = np.zeros((1, 2, 3))
_ONE_QUAD = np.zeros((1, 4, 3))


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """``[..., 4]`` wxyz quaternions (normalised here) -> ``[..., 3, 3]`` rotation matrices."""
    q = np.asarray(q, np.float64)
    w, x, y, z = np.moveaxis(q / np.linalg.norm(q, axis=-1, keepdims=True), -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


@dataclasses.dataclass
class RobotShapes:
    """The robot's geometry placed in the world at one frame (m, Z up), ready to draw.

    Attributes:
        capsules: ``[C, 2, 3]`` the two end centres of each capsule; ``capsule_radius [C]``;
            ``capsule_geoms [C]`` the geom (index into the :class:`RobotGeometry`) of each.
        cylinders, cylinder_radius, cylinder_geoms: the same for the cylinders (their end faces' centres).
        spheres: ``[S, 3]`` centres; ``sphere_radius [S]``; ``sphere_geoms [S]``.
        faces: ``[F, 4, 3]`` the boxes' faces (6 per box); ``face_geoms [F]``.
        lines: ``[L, 2, 3]`` segments: the ellipsoids' principal ellipses and the soles' outlines.
        dots: ``[D, 3]`` the meshes' surface points.
    """

    capsules: np.ndarray
    capsule_radius: np.ndarray
    capsule_geoms: np.ndarray
    cylinders: np.ndarray
    cylinder_radius: np.ndarray
    cylinder_geoms: np.ndarray
    spheres: np.ndarray
    sphere_radius: np.ndarray
    sphere_geoms: np.ndarray
    faces: np.ndarray
    face_geoms: np.ndarray
    lines: np.ndarray
    dots: np.ndarray


def _hull_2d(p: np.ndarray) -> np.ndarray:
    """Indices of the convex hull of ``p [N, 2]``, counter-clockwise (Andrew's monotone chain)."""
    order = np.lexsort((p[:, 1], p[:, 0]))

    def half(idx):
        out: list[int] = []
        for i in idx:
            while len(out) >= 2:
                a, b = p[out[-2]], p[out[-1]]
                if (b[0] - a[0]) * (p[i][1] - a[1]) - (b[1] - a[1]) * (p[i][0] - a[0]) > 1e-15:
                    break
                out.pop()
            out.append(int(i))
        return out

    lower, upper = half(order), half(order[::-1])
    return np.array(lower[:-1] + upper[:-1], np.int64)


def _outline(points: np.ndarray) -> np.ndarray:
    """``[L, 2, 3]`` the closed outline of points that lie (about) in a plane: their hull in that plane."""
    if len(points) < 2:
        return np.zeros((0, 2, 3))
    centre = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centre)
    ring = points[_hull_2d((points - centre) @ vt[:2].T)] if len(points) > 2 else points
    if len(ring) < 2:
        return np.zeros((0, 2, 3))
    return np.stack([ring, np.roll(ring, -1, axis=0)], axis=1)[: len(ring) if len(ring) > 2 else 1]


def _ellipses(size: np.ndarray) -> np.ndarray:
    """``[3 * _RING, 2, 3]`` the three principal ellipses of an ellipsoid of half sizes ``size``, geom frame."""
    t = np.linspace(0.0, 2.0 * math.pi, _RING + 1)
    c, s, z = np.cos(t), np.sin(t), np.zeros_like(t)
    rings = [np.stack(v, -1) * size for v in ((c, s, z), (c, z, s), (z, c, s))]
    return np.concatenate([np.stack([r[:-1], r[1:]], axis=1) for r in rings])


def robot_shapes(geometry: RobotGeometry, xpos: np.ndarray, xmat: np.ndarray) -> RobotShapes:
    """Place the robot's geoms and surface points in the world at one frame.

    A geom's world frame is its body's composed with the geom's own: ``R = xmat[b] @ R(geom_quat)``,
    ``p = xpos[b] + xmat[b] @ geom_pos`` (MuJoCo's ``geom_xmat``, ``geom_xpos``).

    Args:
        geometry: the robot's geometry (body frames).
        xpos: ``[B, 3]`` the bodies' world positions, m.
        xmat: ``[B, 3, 3]`` the bodies' rotations, body -> world.

    Returns:
        A :class:`RobotShapes`.
    """
    g = geometry
    b = g.geom_body
    R = xmat[b] @ quat_to_matrix(g.geom_quat) if len(b) else np.zeros((0, 3, 3))  # [G, 3, 3]
    p = xpos[b] + np.einsum("gij,gj->gi", xmat[b], g.geom_pos) if len(b) else np.zeros((0, 3))
    types = np.asarray(g.geom_type, dtype=object)

    def ends(kind):
        idx = np.flatnonzero(types == kind) if len(b) else np.zeros(0, np.int64)
        half = R[idx, :, 2] * g.geom_size[idx, 1:2]
        return np.stack([p[idx] - half, p[idx] + half], axis=1).reshape(-1, 2, 3), g.geom_size[idx, 0], idx

    capsules, capsule_radius, capsule_geoms = ends("capsule")
    cylinders, cylinder_radius, cylinder_geoms = ends("cylinder")
    spheres = np.flatnonzero(types == "sphere") if len(b) else np.zeros(0, np.int64)
    boxes = np.flatnonzero(types == "box") if len(b) else np.zeros(0, np.int64)
    corners = p[boxes, None] + np.einsum("gij,gkj->gki", R[boxes], _BOX_CORNERS * g.geom_size[boxes, None])
    faces = corners[:, _BOX_FACES].reshape(-1, 4, 3)
    lines = [p[k] + _ellipses(g.geom_size[k]) @ R[k].T for k in np.flatnonzero(types == "ellipsoid")]
    with_geom = set(b.tolist())
    dots = []
    for body in dict.fromkeys(g.point_body.tolist()):  # each body once, in order
        pts = xpos[body] + g.point_pos[g.point_body == body] @ xmat[body].T
        if body not in with_geom:  # a sole: its outline
            lines.append(_outline(pts))
        elif "mesh" in types[b == body]:
            dots.append(pts)
    return RobotShapes(
        capsules, capsule_radius, capsule_geoms, cylinders, cylinder_radius, cylinder_geoms,
        p[spheres].reshape(-1, 3), g.geom_size[spheres, 0], spheres, faces, np.repeat(boxes, 6),
        np.concatenate(lines).reshape(-1, 2, 3) if lines else np.zeros((0, 2, 3)),
        np.concatenate(dots).reshape(-1, 3) if dots else np.zeros((0, 3)))


def _view_direction(ax) -> np.ndarray:
    """The unit vector from the scene towards the camera (matplotlib's elevation and azimuth)."""
    e, a = math.radians(ax.elev), math.radians(ax.azim)
    return np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])


def pixels_per_metre(ax, centre: np.ndarray) -> float:
    """How many pixels one metre across the view at ``centre [3]`` spans on ``ax`` (a 3-D axes, its limits
    set): the projected length of a horizontal metre perpendicular to the line of sight."""
    from mpl_toolkits.mplot3d import proj3d

    ax.apply_aspect()  # the axes' final box, as drawing will set it
    a = math.radians(ax.azim)
    across = np.array([-math.sin(a), math.cos(a), 0.0])
    M = ax.get_proj()
    ends = [ax.transData.transform(proj3d.proj_transform(*x, M)[:2]) for x in (centre, centre + across)]
    return float(np.linalg.norm(ends[1] - ends[0]))


class RobotArtist:
    """The artists of a robot's geometry on a 3-D axes; :meth:`update` moves them to a frame.

    Only the kinds of shape the robot has get artists, made once; their data change every frame.
    """

    def __init__(self, ax, geometry: RobotGeometry, color, *, zorder: float = 3.0):
        from matplotlib.colors import to_rgb
        from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

        self.ax, self.g = ax, geometry
        self.rgb = np.array(to_rgb(color))
        dark = tuple(_DARK * self.rgb)
        kinds = set(geometry.geom_type)
        self.dpi = ax.figure.dpi
        self.boxes = self.capsules = self.cylinders = None
        if "box" in kinds:
            self.boxes = Poly3DCollection(_ONE_QUAD, zorder=zorder, edgecolors=dark, linewidths=0.6)
            ax.add_collection3d(self.boxes)
        for kind, cap in (("capsule", "round"), ("cylinder", "butt")):
            if kind in kinds:  # the outline (wider, dark) under the fill
                pair = tuple(Line3DCollection(_ONE_SEGMENT, colors=c, capstyle=cap, zorder=zorder + 0.1 + 0.01 * i)
                             for i, c in enumerate((dark, tuple(self.rgb))))
                for coll in pair:
                    ax.add_collection3d(coll)
                setattr(self, f"{kind}s", pair)
        # a sphere is a round marker as wide as it: one artist each (a marker's size is per artist)
        self.spheres = [ax.plot([], [], [], "o", color=tuple(self.rgb), mec=dark, mew=_OUTLINE_POINTS / 2,
                                zorder=zorder + 0.2, linestyle="")[0] for t in geometry.geom_type if t == "sphere"]
        self.lines = Line3DCollection(_ONE_SEGMENT, colors=dark, linewidths=1.2, zorder=zorder + 0.3)
        ax.add_collection3d(self.lines)
        (self.dots,) = ax.plot([], [], [], ".", color=dark, ms=2.0, zorder=zorder + 0.3, linestyle="")

    def update(self, xpos: np.ndarray, xmat: np.ndarray, centre: np.ndarray) -> RobotShapes:
        """Draw the robot with bodies at ``xpos [B, 3]``, ``xmat [B, 3, 3]``; ``centre [3]`` is where the
        view's scale is measured (the axes' limits must be set). Returns what it drew."""
        s = robot_shapes(self.g, xpos, xmat)
        points = 72.0 / self.dpi * pixels_per_metre(self.ax, centre)  # points per metre
        eye = _view_direction(self.ax)
        for pair, segs, radius in ((self.capsules, s.capsules, s.capsule_radius),
                                   (self.cylinders, s.cylinders, s.cylinder_radius)):
            if pair is None:
                continue
            order = np.argsort(segs.mean(axis=1) @ eye)  # the far ones first
            width = 2.0 * radius[order] * points
            for coll, w in zip(pair, (width + _OUTLINE_POINTS, width)):
                coll.set_segments(segs[order])
                coll.set_linewidths(w)
        if self.boxes is not None:
            n = np.cross(s.faces[:, 1] - s.faces[:, 0], s.faces[:, 2] - s.faces[:, 0])
            n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
            shade = 0.55 + 0.45 * np.abs(n @ _LIGHT)
            self.boxes.set_verts(s.faces)
            self.boxes.set_facecolor(np.clip(shade[:, None] * self.rgb, 0.0, 1.0))
        for artist, c, r in zip(self.spheres, s.spheres, s.sphere_radius):
            artist.set_data_3d([c[0]], [c[1]], [c[2]])
            artist.set_markersize(2.0 * r * points)
        self.lines.set_segments(s.lines)
        self.dots.set_data_3d(s.dots[:, 0], s.dots[:, 1], s.dots[:, 2])
        return s
