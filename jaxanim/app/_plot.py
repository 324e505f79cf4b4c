"""Stick-figure plots of one pose with matplotlib (the optional ``jaxanim[plot]`` extra).

matplotlib is imported only when a function here is called. On a Linux machine without a display
(no ``DISPLAY``/``WAYLAND_DISPLAY``, no ``MPLBACKEND``), the non-interactive Agg backend is selected
before pyplot is first imported; :func:`save_pose_png` never touches pyplot at all.

The vertical axis of the plot is the skeleton's up axis (``up="y"`` for BVH files, whose
convention is Y up), the three axes have the same scale, and the data axes are permuted cyclically
(``(z, x, y)`` onto the plot's ``(X, Y, Z)``) so the figure is not mirrored.
"""

from __future__ import annotations

import os
import re
import sys

import numpy as np

from .._errors import JaxanimError
from ..kinematics._fk import FKResult
from ..skeleton._skeleton import Skeleton

__all__ = ["plot_pose", "save_pose_png"]

# data axis shown on the plot's (X, Y, Z), for each up axis: cyclic permutations, no mirroring
_AXIS_ORDER = {"x": (1, 2, 0), "y": (2, 0, 1), "z": (0, 1, 2)}
_COLORS = {"left": "tab:blue", "right": "tab:red", "center": "0.2"}



def _import_matplotlib(pyplot: bool):
    """Import matplotlib (and pyplot, on a headless Linux machine with the Agg backend)."""
    try:
        import matplotlib
    except ImportError:
        raise JaxanimError("plotting needs matplotlib: install jaxanim[plot] (pip install 'jaxanim[plot]')") from None
    if not pyplot:
        return matplotlib, None
    headless = sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    if headless and "MPLBACKEND" not in os.environ and "matplotlib.pyplot" not in sys.modules:
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return matplotlib, plt


def _side(name: str) -> str:
    """``"left"``, ``"right"`` or ``"center"`` from a joint name.

    Recognizes ``LeftArm``/``arm_left``, ``LHipJoint``/``L_arm`` (a capital ``L`` then a capital or
    ``_``) and ``arm_l``/``arm.l``, after dropping a ``namespace:`` prefix (``mixamorig:LeftArm``).
    """
    n = name.rsplit(":", 1)[-1]
    low = n.lower()
    for side, word in (("left", "left"), ("right", "right")):
        c = word[0]
        if (
            low.startswith(word)
            or low.endswith(word)
            or re.match(rf"{c.upper()}[A-Z_]", n)
            or low.startswith(f"{c}_")
            or re.search(rf"[_.]{c}$", low)
        ):
            return side
    return "center"


def _pose_arrays(skeleton: Skeleton, fk_result: FKResult) -> tuple[np.ndarray, np.ndarray]:
    if not isinstance(skeleton, Skeleton):
        raise JaxanimError(f"skeleton: expected a jaxanim.Skeleton, got {type(skeleton).__name__}")
    if not isinstance(fk_result, FKResult):
        raise JaxanimError(f"fk_result: expected a jaxanim.FKResult, got {type(fk_result).__name__}")
    J, E = skeleton.num_joints, skeleton.num_end_sites
    p = np.asarray(fk_result.positions, dtype=np.float64)
    e = np.asarray(fk_result.end_site_positions, dtype=np.float64)
    hint = "; plot one frame, e.g. jax.tree.map(lambda x: x[k], fk_result)" if p.ndim == 3 else ""
    if p.shape != (J, 3):
        raise JaxanimError(f"fk_result.positions: expected shape (joints, 3) = ({J}, 3), got {p.shape}{hint}")
    if e.shape != (E, 3):
        raise JaxanimError(f"fk_result.end_site_positions: expected shape (end_sites, 3) = ({E}, 3), got {e.shape}{hint}")
    if not (np.isfinite(p).all() and np.isfinite(e).all()):
        raise JaxanimError("fk_result: positions are not all finite; cannot plot them")
    return p, e


def plot_pose(
    skeleton: Skeleton,
    fk_result: FKResult,
    *,
    ax=None,
    title: str | None = None,
    up: str = "y",
    view: tuple[float, float] | None = (10.0, -60.0),
    shadow: bool = True,
):
    """Draw one pose as a 3-D stick figure.

    Bones are lines from each joint to its children and to its End Sites; joints are dots. Bones of
    joints whose names say left (``Left*``, ``L*``, ``*_l``) are blue, right ones red, the others
    dark grey. The three axes have equal scale and the skeleton's up axis is vertical.

    Args:
        skeleton: the tree.
        fk_result: the :class:`~jaxanim.FKResult` of **one** pose: ``positions [joints, 3]`` and
            ``end_site_positions [end_sites, 3]`` (file units).
        ax: a matplotlib 3-D axes to draw into (``fig.add_subplot(projection="3d")``); default a
            new pyplot figure.
        title: the axes title.
        up: the skeleton's up axis, ``"y"`` (BVH convention), ``"z"`` or ``"x"``.
        view: ``(elevation, azimuth)`` of the camera in degrees, or ``None`` to keep the axes'.
        shadow: also draw the figure's vertical projection onto the ground (the lowest height).

    Returns:
        The matplotlib axes.

    Raises:
        JaxanimError: matplotlib is not installed, ``fk_result`` does not hold one pose of
            ``skeleton``, or ``up`` is not an axis name.
    """
    if up not in _AXIS_ORDER:
        raise JaxanimError(f"up: expected one of {sorted(_AXIS_ORDER)}, got {up!r}")
    p, e = _pose_arrays(skeleton, fk_result)
    if ax is None:
        _, plt = _import_matplotlib(pyplot=True)
        ax = plt.figure(figsize=(6, 6)).add_subplot(projection="3d")
    else:
        _import_matplotlib(pyplot=False)
    if getattr(ax, "name", None) != "3d":
        raise JaxanimError("ax: expected a 3-D axes, e.g. fig.add_subplot(projection='3d')")
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    order = list(_AXIS_ORDER[up])
    pts = np.concatenate([p, e], axis=0)[:, order]  # plot coordinates, vertical last
    J = skeleton.num_joints
    bones = [(par, j, _side(skeleton.names[j])) for j, par in enumerate(skeleton.parents) if par >= 0]
    bones += [(par, J + k, _side(skeleton.names[par])) for k, par in enumerate(skeleton.end_site_parents)]

    ground = pts[:, 2].min()
    if shadow and bones:
        flat = pts.copy()
        flat[:, 2] = ground
        segs = np.stack([np.stack([flat[a], flat[b]]) for a, b, _ in bones])
        ax.add_collection3d(Line3DCollection(segs, colors="0.75", linewidths=2.0))
    for side, color in _COLORS.items():
        segs = [np.stack([pts[a], pts[b]]) for a, b, s in bones if s == side]
        if segs:
            ax.add_collection3d(Line3DCollection(np.stack(segs), colors=color, linewidths=2.5))
    ax.scatter(pts[:J, 0], pts[:J, 1], pts[:J, 2], s=10, c="k", depthshade=False)

    center = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    half = 0.55 * max(float(np.ptp(pts, axis=0).max()), 1e-9)
    ax.set_xlim(center[0] - half, center[0] + half)
    ax.set_ylim(center[1] - half, center[1] + half)
    ax.set_zlim(center[2] - half, center[2] + half)
    ax.set_box_aspect((1.0, 1.0, 1.0), zoom=1.1)
    labels = "xyz"
    ax.set_xlabel(labels[order[0]])
    ax.set_ylabel(labels[order[1]])
    ax.set_zlabel(f"{labels[order[2]]} (up)")
    if view is not None:
        ax.view_init(elev=view[0], azim=view[1])
    if title is not None:
        ax.set_title(title)
    return ax


def save_pose_png(path, skeleton: Skeleton, fk_result: FKResult, *, dpi: int = 100, size: float = 6.0, **kw) -> None:
    """Draw one pose with :func:`plot_pose` and save it as a PNG (without pyplot).

    Args:
        path: the file to write.
        skeleton, fk_result: as :func:`plot_pose`.
        dpi: resolution; the image is ``size * dpi`` pixels square.
        size: figure width and height in inches.
        **kw: passed to :func:`plot_pose` (``title``, ``up``, ``view``, ``shadow``).

    Raises:
        JaxanimError: as :func:`plot_pose`.
        OSError: the file cannot be written.
    """
    _import_matplotlib(pyplot=False)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(size, size))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(projection="3d")
    fig.subplots_adjust(left=0.02, right=0.9, bottom=0.06, top=0.92)
    plot_pose(skeleton, fk_result, ax=ax, **kw)
    fig.savefig(path, dpi=dpi, format="png")
