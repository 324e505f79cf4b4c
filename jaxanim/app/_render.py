"""``jaxanim render``: a clip (or two, side by side) animated as a 3-D stick figure in a GIF or MP4.

The frames are drawn with matplotlib (the optional ``jaxanim[plot]`` extra) on an Agg canvas, never
through pyplot, and written by matplotlib's animation writers: Pillow for ``.gif``, ffmpeg for
``.mp4`` (where ``matplotlib.animation.writers.is_available("ffmpeg")``; elsewhere a clear error).

* **FK** of all frames of each clip is one batched call (:func:`._common.batched_fk`); the artists
  are made once and only their data change from frame to frame.
* **Timeline.** The output runs at ``--fps`` (default: the first clip's frame rate) from the first
  to the last selected frame of the first clip (``--frames A:B``, Python slice style, B excluded),
  or, without ``--frames``, over the longer of the clips. Each panel shows the frame of its clip
  nearest to the output time, so clips of different frame rates stay aligned by time, and a clip
  that has ended is held at its last frame.
* **Camera.** ``--camera follow`` (the default) keeps the view centred horizontally on the root
  joint, with axis limits of a fixed size over the whole clip (set by the largest pose), so the
  figure stays large and the ground grid, fixed in the world, slides past as the character walks.
  ``--camera fixed`` sets the axis limits once to the bounding box of the whole clip.
  The skeleton's up axis (Y, the BVH convention) is vertical and the axes have equal scale.
* **Look.** Bones as in :func:`jaxanim.app.plot_pose` (left blue, right red, the rest dark grey),
  joints as black dots, the figure's shadow on the ground (the lowest point of the clip), a ground
  grid, the file name as each panel's title and the time and frame number in its corner.
  ``--mesh`` adds the capsule skin of the skeleton (:mod:`jaxanim.skinning`: ``capsule_mesh``,
  ``heuristic_weights``, ``skin_motion`` with LBS), shaded by a fixed light.
* **Retarget results.** A ``.npz`` from ``jaxanim retarget`` (:mod:`._retarget_clip`) is one panel in
  the robot's frame (Z up, ground at z = 0, no FK): the robot in orange, drawn from its collision
  geometry (:mod:`._robot_draw`: capsules, boxes, spheres, ..., over thin sticks between its body
  origins; a result without the geometry keys as thick sticks), beside its source skeleton in blue,
  shifted along +Y just clear of it, a foot in stance marked green, a legend
  naming both files, seen in 3/4 from the robot's front right (:func:`render_retarget`, which
  ``jaxanim retarget --render`` calls too). ``--fps``, ``--frames``, ``--camera`` and ``--size`` work
  as for clips; ``--compare`` and ``--mesh`` do not apply.
* **GIF.** One palette for all frames, without dithering (what stands still keeps its pixels),
  and frame durations in GIF's centiseconds that add up to the clip's time (:func:`_gif_writer`).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import pathlib
import time
from collections.abc import Mapping, Sequence

import numpy as np

from .._errors import JaxanimError
from ..skeleton._skeleton import Motion
from ._common import _UI, _Clip, _clip_fk, _duration, _load, _ms, _num
from ._plot import _AXIS_ORDER, _COLORS, _import_matplotlib, _side
from ._retarget_clip import (
    RetargetClip,
    RetargetScene,
    is_retarget_file,
    load_retarget,
    retarget_scene,
)
from ._robot_draw import RobotArtist
from ._simulate import _check_writable

__all__ = ["RenderInfo", "add_render_parser", "render_clips", "render_retarget"]

_WRITERS = {".gif": "pillow", ".mp4": "ffmpeg"}
_CAMERAS = ("follow", "fixed")
_DPI = 100
_VIEW = (12.0, -60.0)  # (elevation, azimuth) in degrees, as plot_pose's
# a robot faces +X (Z up): a 3/4 view from its front right, so its source, beside it at +Y, stands on the right
_RETARGET_VIEW = (12.0, -35.0)
_ROBOT_COLOR, _SOURCE_COLOR, _CONTACT_COLOR = "tab:orange", "tab:blue", "tab:green"
_LIGHT = np.array([-0.4, -0.6, 1.0]) / np.linalg.norm([-0.4, -0.6, 1.0])  # plot coordinates, vertical last
_SKIN_RGB = np.array([0.55, 0.68, 0.85])
# the collections start with a placeholder (matplotlib's add_collection3d cannot autoscale an empty one);
# update() replaces it before the first frame is drawn, and the axis limits are always set explicitly
_ONE_SEGMENT = np.zeros((1, 2, 3))
_ONE_TRIANGLE = np.zeros((1, 3, 3))


@dataclasses.dataclass
class RenderInfo:
    """What :func:`render_clips` wrote."""

    out: pathlib.Path
    frames: int  # output frames
    fps: float
    width: int  # pixels
    height: int
    fk_seconds: float  # FK of every clip (compile included)
    skin_seconds: float  # --mesh skinning (compile included), 0 without
    draw_seconds: float  # drawing and encoding


@dataclasses.dataclass
class _Panel:
    """One clip in plot coordinates (the data axes permuted so the up axis is last)."""

    title: str
    points: np.ndarray  # [frames, joints + end_sites, 3]
    bones: list[tuple[int, int, str]]  # (from point, to point, side)
    num_joints: int
    frame_time: float
    index: np.ndarray  # [output frames] the clip's frame shown at each output frame
    vertices: np.ndarray | None = None  # [frames, V, 3] with --mesh (only the shown frames are filled)
    faces: np.ndarray | None = None  # [T, 3]


# ------------------------------------------------------------------------------------------------
# Options
# ------------------------------------------------------------------------------------------------


def _writer_name(out: str | os.PathLike) -> str:
    ext = pathlib.Path(out).suffix.lower()
    if ext not in _WRITERS:
        raise JaxanimError(f"--out {out}: unknown output extension {ext or '(none)'!r}: "
                           f"expected {' or '.join(_WRITERS)}")
    return _WRITERS[ext]


def _check_writer(name: str, out) -> None:
    _import_matplotlib(pyplot=False)
    from matplotlib import animation

    if not animation.writers.is_available(name):
        if name == "ffmpeg":
            raise JaxanimError(f"--out {out}: writing MP4 needs ffmpeg, which was not found: install it "
                               "(apt-get install ffmpeg, brew install ffmpeg or conda install ffmpeg, or point "
                               "matplotlib's rcParams['animation.ffmpeg_path'] at it), or write a GIF "
                               "(--out clip.gif)")
        raise JaxanimError(f"--out {out}: matplotlib's {name} animation writer is not available "
                           "(GIF needs Pillow: pip install pillow)")


#: The largest ``--size`` (pixels) and ``--fps``: a picture of 70000 pixels grew to 23 GB, and 1e6 fps drew
#: thousands of frames from two.
MAX_SIZE = 4096
MAX_FPS = 240.0


def _check_fps(fps: float | None) -> None:
    if fps is not None and not (math.isfinite(fps) and 0 < fps <= MAX_FPS):
        raise JaxanimError(f"--fps {fps:g}: expected a positive number of frames per second, at most {MAX_FPS:g}")


def _check_output(out, fps, camera: str, size) -> str:
    """The checks every render makes before drawing anything; returns the writer's name."""
    writer_name = _writer_name(out)
    _check_fps(fps)
    if camera not in _CAMERAS:
        raise JaxanimError(f"--camera {camera}: expected one of {', '.join(_CAMERAS)}")
    if not (isinstance(size, int) and 32 <= size <= MAX_SIZE):
        raise JaxanimError(f"--size {size}: expected 32 to {MAX_SIZE} pixels")
    return writer_name


def _parse_frames(spec: str) -> tuple[int | None, int | None]:
    """``"A:B"``, ``"A:"``, ``":B"`` -> ``(A, B)`` (``None`` where omitted)."""
    parts = spec.split(":")
    try:
        if len(parts) != 2:
            raise ValueError
        a, b = (int(x) if x.strip() else None for x in parts)
    except ValueError:
        raise JaxanimError(f"--frames {spec}: expected A:B (frame indices, B excluded), e.g. 0:60") from None
    return a, b


def _frame_range(frames: tuple[int | None, int | None] | None, clip: _Clip | RetargetClip) -> tuple[int, int] | None:
    """The selected ``[A, B)`` of ``clip``, checked, or ``None`` for all frames."""
    n = clip.num_frames if isinstance(clip, RetargetClip) else clip.motion.num_frames
    if n == 0:
        raise JaxanimError(f"{clip.label} has no frames")
    if frames is None:
        return None
    a = 0 if frames[0] is None else frames[0]
    b = n if frames[1] is None else frames[1]
    if not 0 <= a < b <= n:
        spec = f"{'' if frames[0] is None else frames[0]}:{'' if frames[1] is None else frames[1]}"
        raise JaxanimError(f"--frames {spec}: expected A:B with 0 <= A < B <= {n} ({clip.label} has {n} frames)")
    return a, b


# ------------------------------------------------------------------------------------------------
# Data: FK, timeline, mesh
# ------------------------------------------------------------------------------------------------


def _timeline(clips: Sequence[_Clip], selected: tuple[int, int] | None, fps: float) -> np.ndarray:
    """Output times (seconds from the clips' first frame)."""
    ft0 = float(clips[0].motion.frame_time)
    if selected is not None:
        t0, t1 = selected[0] * ft0, (selected[1] - 1) * ft0
    else:
        t0, t1 = 0.0, max((c.motion.num_frames - 1) * float(c.motion.frame_time) for c in clips)
    k = math.floor((t1 - t0) * fps + 1e-6) + 1
    return t0 + np.arange(k) / fps


def _panel(clip: _Clip, times: np.ndarray, ui: _UI) -> tuple[_Panel, float]:
    sk, m = clip.skeleton, clip.motion
    t0 = time.perf_counter()
    fk = _clip_fk(clip, ui).result
    order = list(_AXIS_ORDER["y"])
    pts = np.concatenate([np.asarray(fk.positions, np.float64), np.asarray(fk.end_site_positions, np.float64)],
                         axis=1)[..., order]
    seconds = time.perf_counter() - t0
    if not np.isfinite(pts).all():
        raise JaxanimError(f"{clip.label}: the joint positions are not all finite; cannot draw them")
    J = sk.num_joints
    bones = [(par, j, _side(sk.names[j])) for j, par in enumerate(sk.parents) if par >= 0]
    bones += [(par, J + k, _side(sk.names[par])) for k, par in enumerate(sk.end_site_parents)]
    ft = float(m.frame_time)
    index = np.clip(np.rint(times / ft).astype(np.int64), 0, m.num_frames - 1)
    return _Panel(clip.path.name, pts, bones, J, ft, index), seconds


def _skin(clip: _Clip, panel: _Panel, ui: _UI) -> None:
    """Fill ``panel.vertices`` / ``faces`` with the capsule skin at the shown frames (LBS)."""
    from .. import skinning
    sk, m = clip.skeleton, clip.motion
    shown = np.unique(panel.index)
    ui.progress(f"skinning the capsule mesh of {clip.label} at {shown.size} frames (LBS)")
    mesh = skinning.capsule_mesh(sk)
    weights = skinning.heuristic_weights(sk, mesh.vertices)
    sub = Motion(m.rotations[shown], m.translations[shown], m.frame_time)
    v = np.asarray(skinning.skin_motion(sk, sub, mesh, weights, method="lbs"), np.float64)
    if v.ndim != 3 or v.shape[0] != shown.size or v.shape[2] != 3:
        raise JaxanimError(f"skin_motion returned shape {v.shape}, expected ({shown.size}, V, 3)")
    vertices = np.zeros((m.num_frames, v.shape[1], 3))
    vertices[shown] = v[..., list(_AXIS_ORDER["y"])]
    panel.vertices = vertices
    panel.faces = np.asarray(mesh.faces, np.int64)


# ------------------------------------------------------------------------------------------------
# Drawing
# ------------------------------------------------------------------------------------------------


def _nice_step(span: float) -> float:
    """A 1, 2 or 5 x 10^k step that cuts ``span`` into about 6 cells."""
    raw = max(span / 6.0, 1e-12)
    e = 10.0 ** math.floor(math.log10(raw))
    return min((s * e for s in (1.0, 2.0, 5.0, 10.0)), key=lambda s: abs(math.log(s / raw)))


class _Stage:
    """What every panel has, made once: the axes (hidden, equal scale, the up axis vertical), the
    camera, the ground grid, the shadows and the time label.

    ``shown [frames, P, 3]`` is everything drawn at the frames shown (it sets the view's size),
    ``track [frames, 2]`` the horizontal point the ``follow`` camera centres on at those frames,
    ``ground`` the height of the grid and the shadows.
    """

    def __init__(self, ax, title: str, shown: np.ndarray, track: np.ndarray, ground: float, camera: str, size: int,
                 view: tuple[float, float] = _VIEW):
        from mpl_toolkits.mplot3d.art3d import Line3DCollection

        self.ax, self.camera, self.ground = ax, camera, ground
        low, top = min(ground, float(shown[..., 2].min())), float(shown[..., 2].max())
        if camera == "follow":
            radius = float(np.linalg.norm(shown[..., :2] - track[:, None], axis=-1).max())
            self.half = 0.55 * max(top - low, 2.0 * radius, 1e-9)
        else:
            lo, hi = shown.reshape(-1, 3).min(axis=0), shown.reshape(-1, 3).max(axis=0)
            lo[2] = low
            self.half = 0.55 * max(float((hi - lo).max()), 1e-9)
            self.center = 0.5 * (lo + hi)
        self.step = _nice_step(2.0 * self.half)
        self.zlim = (low - 0.1 * self.half, low + 1.9 * self.half)

        ax.set_axis_off()
        ax.computed_zorder = False  # the grid under the shadow under the skin under the bones
        ax.view_init(elev=view[0], azim=view[1])
        ax.set_box_aspect((1.0, 1.0, 1.0), zoom=1.35)
        ax.set_title(title, fontsize=max(6.0, size / 36.0), pad=0)
        self.grid = Line3DCollection(_ONE_SEGMENT, colors="0.82", linewidths=0.8, zorder=0)
        self.shadow = Line3DCollection(_ONE_SEGMENT, colors="0.72", linewidths=2.0, zorder=1)
        ax.add_collection3d(self.grid)
        ax.add_collection3d(self.shadow)
        self.label = ax.text2D(0.02, 0.02, "", transform=ax.transAxes, fontsize=max(5.0, size / 45.0), color="0.3")
        if camera == "fixed":
            self._limits(self.center[:2])

    def _limits(self, c: np.ndarray) -> None:
        h = self.half
        self.ax.set_xlim(c[0] - h, c[0] + h)
        self.ax.set_ylim(c[1] - h, c[1] + h)
        self.ax.set_zlim(*self.zlim)
        s, g = self.step, self.ground
        xs = np.arange(math.ceil((c[0] - h) / s), math.floor((c[0] + h) / s) + 1) * s
        ys = np.arange(math.ceil((c[1] - h) / s), math.floor((c[1] + h) / s) + 1) * s
        segs = [((x, c[1] - h, g), (x, c[1] + h, g)) for x in xs] + [((c[0] - h, y, g), (c[0] + h, y, g)) for y in ys]
        self.grid.set_segments(np.array(segs, dtype=np.float64).reshape(-1, 2, 3))

    def _move(self, pts: np.ndarray, pairs: np.ndarray, centre: np.ndarray) -> None:
        """The camera (``follow``) and the shadows of the segments ``pairs`` of ``pts [P, 3]``."""
        if self.camera == "follow":
            self._limits(centre)
        flat = pts.copy()
        flat[:, 2] = self.ground
        self.shadow.set_segments(np.stack([flat[pairs[:, 0]], flat[pairs[:, 1]]], axis=1))


class _PanelArtist(_Stage):
    """The artists of one clip's panel; :meth:`update` moves them to output frame ``k``."""

    def __init__(self, fig, ax, panel: _Panel, camera: str, size: int):
        from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

        self.p = panel
        shown = panel.points[np.unique(panel.index)]  # [frames, P, 3]: limits over what is drawn
        extra = panel.vertices[np.unique(panel.index)] if panel.vertices is not None else shown[:, :0]
        allpts = np.concatenate([shown, extra], axis=1)
        super().__init__(ax, panel.title, allpts, shown[:, 0, :2], float(allpts[..., 2].min()), camera, size)
        self.mesh = None
        if panel.vertices is not None:
            self.mesh = Poly3DCollection(_ONE_TRIANGLE, zorder=2, linewidths=0.0, alpha=0.55)
            ax.add_collection3d(self.mesh)
        self.sides = []
        width = 2.5 if panel.vertices is None else 1.5
        for side, color in _COLORS.items():
            pairs = np.array([(a, b) for a, b, s in panel.bones if s == side], dtype=np.int64).reshape(-1, 2)
            if len(pairs):
                coll = Line3DCollection(_ONE_SEGMENT, colors=color, linewidths=width, zorder=3)
                ax.add_collection3d(coll)
                self.sides.append((coll, pairs))
        self.pairs = np.array([(a, b) for a, b, _ in panel.bones], dtype=np.int64).reshape(-1, 2)
        (self.joints,) = ax.plot([], [], [], "o", ms=max(1.5, size / 150.0), color="k", zorder=4, linestyle="")

    def update(self, k: int, t: float) -> None:
        p = self.p
        f = int(p.index[k])
        pts = p.points[f]
        self._move(pts, self.pairs, pts[0, :2])
        for coll, pairs in self.sides:
            coll.set_segments(np.stack([pts[pairs[:, 0]], pts[pairs[:, 1]]], axis=1))
        J = p.num_joints
        self.joints.set_data_3d(pts[:J, 0], pts[:J, 1], pts[:J, 2])
        if self.mesh is not None:
            tris = p.vertices[f][p.faces]  # [T, 3, 3]
            n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
            n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
            shade = 0.45 + 0.55 * np.abs(n @ _LIGHT)
            self.mesh.set_verts(tris)
            self.mesh.set_facecolor(np.clip(shade[:, None] * _SKIN_RGB, 0.0, 1.0))
        self.label.set_text(f"t = {t:.2f} s   frame {f}/{len(p.points) - 1}")


class _RetargetArtist(_Stage):
    """A robot beside its source on one axes (Z up, ground at z = 0); :meth:`update` shows frame ``f``."""

    def __init__(self, ax, title: str, scene: RetargetScene, shown: np.ndarray, camera: str, size: int):
        from matplotlib.lines import Line2D
        from mpl_toolkits.mplot3d.art3d import Line3DCollection

        self.s = scene
        self.pairs = np.concatenate([scene.sticks, scene.bones])
        super().__init__(ax, title, scene.points[shown], scene.track[shown], 0.0, camera, size, _RETARGET_VIEW)
        # with its geometry, the robot over thin sticks (robots whose files keep little geometry still read)
        self.robot = None if scene.geometry is None else RobotArtist(ax, scene.geometry, _ROBOT_COLOR, zorder=3)
        self.sticks = Line3DCollection(_ONE_SEGMENT, colors=_ROBOT_COLOR, linewidths=3.5 if self.robot is None else 2.0,
                                       zorder=2.9 if self.robot else 3)
        self.bones = Line3DCollection(_ONE_SEGMENT, colors=_SOURCE_COLOR, linewidths=2.0, zorder=3)
        ax.add_collection3d(self.sticks)
        ax.add_collection3d(self.bones)
        ms = max(1.5, size / 150.0)
        (self.dots,) = ax.plot([], [], [], "o", ms=ms, color="k", zorder=4, linestyle="")
        (self.stance,) = ax.plot([], [], [], "o", ms=2.5 * ms, color=_CONTACT_COLOR, zorder=5, linestyle="")
        handles = [Line2D([], [], color=_ROBOT_COLOR, lw=3.5, label=scene.robot_label),
                   Line2D([], [], color=_SOURCE_COLOR, lw=2.0, label=scene.source_label)]
        if (scene.feet >= 0).any():
            handles.append(Line2D([], [], color=_CONTACT_COLOR, marker="o", ms=2.5 * ms, ls="", label="foot in stance"))
        ax.legend(handles=handles, loc="upper left", fontsize=max(4.5, size / 55.0), frameon=False,
                  borderaxespad=0.2, handlelength=1.5)

    def update(self, f: int, t: float) -> None:
        s = self.s
        pts = s.points[f]
        self._move(pts, self.pairs, s.track[f])
        self.sticks.set_segments(np.stack([pts[s.sticks[:, 0]], pts[s.sticks[:, 1]]], axis=1))
        self.bones.set_segments(np.stack([pts[s.bones[:, 0]], pts[s.bones[:, 1]]], axis=1))
        if self.robot is not None:  # body 0, the world, carries no geom
            self.robot.update(np.concatenate([np.zeros((1, 3)), pts[: s.num_robot]]), s.body_xmat[f], pts[0])
        dots = pts[s.num_robot:] if self.robot is not None else pts  # the body origins only as sticks
        self.dots.set_data_3d(dots[:, 0], dots[:, 1], dots[:, 2])
        down = s.feet[(s.feet >= 0) & s.contacts[f]] if s.contacts is not None else s.feet[:0]
        self.stance.set_data_3d(pts[down, 0], pts[down, 1], pts[down, 2])
        self.label.set_text(f"t = {t:.2f} s   frame {f}/{len(s.points) - 1}")


def _gif_writer(animation):
    """A GIF writer on matplotlib's public movie-writer interface, with frame durations that keep time.

    GIF counts frame durations in whole centiseconds, and matplotlib's PillowWriter gives every frame
    ``int(1000 / fps)`` ms, which the file stores rounded down (30 fps: 30 ms, played 10 % fast).
    Here frame ``k`` ends at ``round((k + 1) * 100 / fps)`` centiseconds, so the durations
    alternate (30 fps: 30, 40, 30 ms, ...) and add up to the clip's duration (at least 10 ms each,
    so above 100 fps a GIF runs slow). The frames are grabbed as RGBA (as PillowWriter does) into
    this writer's own list, and written with one shared palette by Pillow.
    """
    import io

    from PIL import Image

    class _GifWriter(animation.AbstractMovieWriter):
        @classmethod
        def isAvailable(cls):
            return True

        def setup(self, fig, outfile, dpi=None):
            super().setup(fig, outfile, dpi=dpi)
            self._rgb = []

        def grab_frame(self, **savefig_kwargs):
            buf = io.BytesIO()
            self.fig.savefig(buf, **{**savefig_kwargs, "format": "rgba", "dpi": self.dpi})
            rgba = Image.frombuffer("RGBA", self.frame_size, buf.getbuffer(), "raw", "RGBA", 0, 1)
            self._rgb.append(rgba.convert("RGB"))

        def finish(self):
            rgb = self._rgb
            # one palette for every frame, from up to 8 of them, and no dithering: what does not move
            # keeps its pixels (a palette per frame makes still parts flicker)
            pick = rgb[:: max(1, len(rgb) // 8)]
            w, h = rgb[0].size
            sample = Image.new("RGB", (w, h * len(pick)))
            for i, f in enumerate(pick):
                sample.paste(f, (0, h * i))
            palette = sample.quantize(colors=255, method=Image.Quantize.MEDIANCUT).getpalette() or []
            palette = np.array(palette[: 255 * 3] + [255, 255, 255], np.int64).reshape(-1, 3)  # exact white too
            frames = [_indexed(f, palette) for f in rgb]
            ends = np.rint(np.arange(1, len(frames) + 1) * 100.0 / self.fps)
            durations = np.maximum(np.diff(ends, prepend=0.0), 1.0) * 10.0
            frames[0].save(self.outfile, save_all=True, append_images=frames[1:],
                           duration=[int(d) for d in durations], loop=0)

    return _GifWriter


def _indexed(image, palette: np.ndarray):
    """``image`` (RGB) as a P image on ``palette [K, 3]``, each colour mapped to its nearest entry.

    Done here because Pillow's own mapping looks colours up at reduced precision, which turned the
    white background into the palette's nearest off-white.
    """
    from PIL import Image

    a = np.asarray(image, dtype=np.int64)
    codes = (a[..., 0] << 16) | (a[..., 1] << 8) | a[..., 2]
    unique, inverse = np.unique(codes.reshape(-1), return_inverse=True)
    colors = np.stack([unique >> 16, (unique >> 8) & 255, unique & 255], axis=-1)
    nearest = ((colors[:, None, :] - palette[None]) ** 2).sum(axis=-1).argmin(axis=1).astype(np.uint8)
    out = Image.frombytes("P", image.size, nearest[inverse].tobytes())
    out.putpalette(palette.astype(np.uint8).reshape(-1).tolist())
    return out


def render_clips(
    clips: Sequence[_Clip],
    out: str | os.PathLike,
    *,
    fps: float | None = None,
    frames: tuple[int | None, int | None] | None = None,
    mesh: bool = False,
    camera: str = "follow",
    size: int = 360,
    ui: _UI | None = None,
) -> RenderInfo:
    """Animate one clip, or several side by side, into a GIF or MP4.

    Args:
        clips: the loaded clips (:func:`._common._load`), one panel each, left to right.
        out: the file to write; ``.gif`` (Pillow) or ``.mp4`` (ffmpeg).
        fps: output frames per second (default: the first clip's frame rate).
        frames: ``(A, B)`` selects frames ``A`` to ``B - 1`` of the first clip (``None`` ends: the
            start, the end); the others are shown at the same times. Default: every frame of the
            longest clip.
        mesh: also draw the skinned capsule mesh (:mod:`jaxanim.skinning`).
        camera: ``"follow"`` (centred on the root) or ``"fixed"`` (the whole clip's bounding box).
        size: the height of the output, and the width of each panel, in pixels (made even).
        ui: where progress goes (default: quiet).

    Returns:
        A :class:`RenderInfo`.

    Raises:
        JaxanimError: an unknown extension, no ffmpeg for MP4, ``fps`` not in (0, MAX_FPS], a ``size`` not
            in [32, MAX_SIZE], frames out of range,
            a camera name not in ``("follow", "fixed")``, no matplotlib.
        OSError: the file cannot be written.
    """
    ui = ui or _UI(quiet=True)
    if not clips:
        raise JaxanimError("no clip to render")
    writer_name = _check_output(out, fps, camera, size)
    _check_writer(writer_name, out)
    _check_writable("--out", os.fspath(out))
    selected = _frame_range(frames, clips[0])
    for c in clips[1:]:
        _frame_range(None, c)
    fps = float(clips[0].motion.fps) if fps is None else float(fps)
    times = _timeline(clips, selected, fps)

    fk_seconds = skin_seconds = 0.0
    panels = []
    for c in clips:
        panel, s = _panel(c, times, ui)
        fk_seconds += s
        if mesh:
            t0 = time.perf_counter()
            _skin(c, panel, ui)
            skin_seconds += time.perf_counter() - t0
        panels.append(panel)

    size += size % 2  # even pixel sizes: h264 needs them
    width, height = size * len(panels), size
    fig = _figure(width, height)
    artists = [_PanelArtist(fig, fig.add_subplot(1, len(panels), i + 1, projection="3d"), p, camera, size)
               for i, p in enumerate(panels)]

    def draw(k: int, t: float) -> None:
        for a in artists:
            a.update(k, t)

    ui.progress(f"drawing {len(times)} frames at {_num(fps)} fps ({width}x{height} px) to {out}")
    draw_seconds = _write(fig, out, writer_name, fps, times, draw)
    return RenderInfo(pathlib.Path(out), len(times), fps, width, height, fk_seconds, skin_seconds, draw_seconds)


def _figure(width: int, height: int):
    """A matplotlib figure of ``width x height`` pixels on an Agg canvas (no pyplot)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width / _DPI, height / _DPI), dpi=_DPI)
    FigureCanvasAgg(fig)
    fig.subplots_adjust(left=0.0, right=1.0, bottom=0.0, top=0.94, wspace=0.0)
    return fig


def _write(fig, out, writer_name: str, fps: float, times: np.ndarray, draw) -> float:
    """Grab ``draw(k, t)`` of every output time into ``out``; returns the seconds it took."""
    from matplotlib import animation

    writer = animation.FFMpegWriter(fps=fps, codec="h264") if writer_name == "ffmpeg" else _gif_writer(animation)(fps=fps)
    t0 = time.perf_counter()
    with writer.saving(fig, os.fspath(out), dpi=_DPI):
        for k, t in enumerate(times):
            draw(k, float(t))
            writer.grab_frame()
    return time.perf_counter() - t0


def render_retarget(
    npz_path_or_mapping,
    out: str | os.PathLike,
    *,
    fps: float | None = None,
    frames: tuple[int | None, int | None] | None = None,
    camera: str = "follow",
    size: int = 360,
    offset: float | None = None,
    ui: _UI | None = None,
) -> RenderInfo:
    """Animate a retarget result, the robot from its collision geometry beside its source skeleton, into a GIF or MP4.

    One panel, the robot's frame (Z up, ground at z = 0): the robot in orange (its geoms; sticks between
    its body origins where the result has no geometry keys), the source in blue
    shifted along +Y (:func:`._retarget_clip.source_shift`), a foot that stands (``contacts``) marked
    green, a legend naming the robot and the source files, the result's file name as the title.

    Args:
        npz_path_or_mapping: the .npz ``jaxanim retarget`` wrote, a dict with the same keys
            (:mod:`._retarget_clip` has the layout), or a loaded :class:`._retarget_clip.RetargetClip`.
        out: the file to write; ``.gif`` (Pillow) or ``.mp4`` (ffmpeg).
        fps: output frames per second (default: the result's ``fps``); frames are picked by time.
        frames: ``(A, B)`` selects frames ``A`` to ``B - 1`` (``None`` ends: the start, the end).
        camera: ``"follow"`` (centred between the two roots) or ``"fixed"`` (the whole clip's box).
        size: the output's width and height, pixels (made even).
        offset: the source's shift along +Y, m (default: just clear of the robot).
        ui: where progress goes (default: quiet).

    Returns:
        A :class:`RenderInfo` (``fk_seconds`` holds the time spent reading the result).

    Raises:
        JaxanimError: a bad result (the message names the file and the key), an unknown extension,
            no ffmpeg for MP4, ``fps`` not in (0, MAX_FPS], a ``size`` not in [32, MAX_SIZE], frames out of
            range, an unknown camera, no matplotlib.
        OSError: the file cannot be written.
    """
    ui = ui or _UI(quiet=True)
    writer_name = _check_output(out, fps, camera, size)
    t0 = time.perf_counter()
    if isinstance(npz_path_or_mapping, RetargetClip):
        clip = npz_path_or_mapping
    else:
        if not isinstance(npz_path_or_mapping, Mapping):
            ui.progress(f"reading {npz_path_or_mapping}")
        clip = load_retarget(npz_path_or_mapping)
    read_seconds = time.perf_counter() - t0
    scene = retarget_scene(clip, offset)
    _check_writer(writer_name, out)
    _check_writable("--out", os.fspath(out))
    a, b = _frame_range(frames, clip) or (0, clip.num_frames)
    fps = clip.fps if fps is None else float(fps)
    ft = clip.frame_time
    times = a * ft + np.arange(math.floor((b - 1 - a) * ft * fps + 1e-6) + 1) / fps
    index = np.clip(np.rint(times / ft).astype(np.int64), 0, clip.num_frames - 1)

    size += size % 2
    fig = _figure(size, size)
    artist = _RetargetArtist(fig.add_subplot(1, 1, 1, projection="3d"), clip.name, scene, np.unique(index), camera,
                             size)
    ui.progress(f"drawing {len(times)} frames of {clip.robot_name} beside {clip.source_name} at {_num(fps)} fps "
                f"({size}x{size} px) to {out}")
    draw_seconds = _write(fig, out, writer_name, fps, times, lambda k, t: artist.update(int(index[k]), t))
    return RenderInfo(pathlib.Path(out), len(times), fps, size, size, read_seconds, 0.0, draw_seconds)


# ------------------------------------------------------------------------------------------------
# The command
# ------------------------------------------------------------------------------------------------


def _cmd_render(args: argparse.Namespace, ui: _UI) -> int:
    # the cheap checks before parsing anything
    if args.out is not None:
        _writer_name(args.out)
    _check_fps(args.fps)
    frames = _parse_frames(args.frames) if args.frames is not None else None
    if is_retarget_file(args.compare):
        raise JaxanimError(f"--compare {args.compare}: a retarget result already holds the robot and its source; "
                           f"render it on its own (jaxanim render {args.compare})")
    if is_retarget_file(args.file):
        return _cmd_render_retarget(args, frames, ui)
    clips = [_load(args.file, ui, args.dtype)]
    if args.compare is not None:
        clips.append(_load(args.compare, ui, args.dtype))
    out = args.out or f"{clips[0].stem}.gif"
    info = render_clips(clips, out, fps=args.fps, frames=frames, mesh=args.mesh, camera=args.camera,
                        size=args.size, ui=ui)
    mb = pathlib.Path(out).stat().st_size / 1e6
    skin = f", skinning {_duration(info.skin_seconds)}" if args.mesh else ""
    ui.result(f"wrote {out}: {info.frames} frames at {_num(info.fps)} fps ({_num(info.frames / info.fps)} s), "
              f"{info.width}x{info.height} px, {mb:.2f} MB; FK {_ms(info.fk_seconds)} (compile included){skin}, "
              f"drawing {_duration(info.draw_seconds)}")
    return 0


def _cmd_render_retarget(args: argparse.Namespace, frames, ui: _UI) -> int:
    """``jaxanim render RESULT.npz``: the robot beside its source (:func:`render_retarget`)."""
    for flag, given in (("--compare", args.compare is not None), ("--mesh", args.mesh)):
        if given:
            raise JaxanimError(f"{flag}: not with a retarget result ({args.file}), which is drawn as the robot's "
                               "geometry beside its source's skeleton")
    ui.progress(f"reading {args.file}")
    t0 = time.perf_counter()
    clip = load_retarget(args.file)
    seconds = time.perf_counter() - t0
    out = args.out or f"{clip.stem}.gif"
    info = render_retarget(clip, out, fps=args.fps, frames=frames, camera=args.camera, size=args.size, ui=ui)
    mb = pathlib.Path(out).stat().st_size / 1e6
    ui.result(f"wrote {out}: {info.frames} frames at {_num(info.fps)} fps ({_num(info.frames / info.fps)} s), "
              f"{info.width}x{info.height} px, {mb:.2f} MB; {clip.robot_name} beside {clip.source_name}; "
              f"reading {_ms(seconds)}, drawing {_duration(info.draw_seconds)}")
    return 0


def add_render_parser(sub, common) -> None:
    p = sub.add_parser("render", parents=[common], help="animate a clip as a 3-D stick figure (GIF or MP4)",
                       description="Animate a clip as a 3-D stick figure with matplotlib (jaxanim[plot]): Pillow "
                                   "writes GIF, ffmpeg writes MP4 (where it is installed). Forward kinematics of all "
                                   "frames is one batched call. With --compare, two clips side by side (e.g. a clip "
                                   "and its simulation), aligned by time, the shorter held at its last frame. The "
                                   "camera follows the root (--camera follow, the default: a fixed-size view centred "
                                   "on the root, the ground grid sliding past) or is fixed on the bounding box of the "
                                   "whole clip (--camera fixed). A retarget result (RESULT.npz, from jaxanim "
                                   "retarget) is drawn as the robot's collision geometry beside its source skeleton, "
                                   "in the robot's frame (Z up).")
    p.add_argument("file", nargs="?", metavar="FILE.bvh|RESULT.npz",
                   help="a BVH file, or a retarget result .npz (default: the shipped walk clip)")
    p.add_argument("--compare", "-c", metavar="OTHER.bvh", help="a second clip, drawn beside the first")
    p.add_argument("--mesh", action="store_true", help="also draw the skinned capsule mesh (jaxanim.skinning, LBS)")
    p.add_argument("--out", "-o", default=None, metavar="OUT.gif|OUT.mp4",
                   help="output file: .gif (Pillow) or .mp4 (needs ffmpeg) (default: <name>.gif here)")
    p.add_argument("--fps", type=float, default=None, metavar="F",
                   help="output frames per second, at most 240 (default: the clip's frame rate; frames are picked by "
                        "time)")
    p.add_argument("--frames", default=None, metavar="A:B",
                   help="frames A to B-1 of FILE (either end may be left out; default: all, and all of OTHER)")
    p.add_argument("--camera", choices=_CAMERAS, default="follow",
                   help="follow the root (default) or fixed on the whole clip's bounding box")
    p.add_argument("--size", type=int, default=360, metavar="PX",
                   help="height of the output and width of each panel, in pixels: 32 to 4096 (default 360)")
    p.set_defaults(func=_cmd_render)
