"""``jaxanim view``: an interactive 3-D viewer of one or more clips in the web browser, on viser.

viser (the optional ``jaxanim[view]`` extra, imported only here) serves a three.js page and keeps it
in sync with the Python side over a websocket. :func:`build_viewer` sets the scene up and returns at
once with a :class:`Viewer` (tests call it, look at the page and close it); the command then runs
:meth:`Viewer.run`, the playback loop, until Ctrl-C.

The scene, Y up (the BVH convention), in file units:

* each clip under ``/clip<i>``: its bones as line segments (left blue, right red, the others
  magenta, :data:`BONE_RGB`), its joints as dark points, its file name as a label above the
  head, and with ``--mesh`` its skinned capsule mesh (:mod:`jaxanim.skinning`: ``capsule_mesh``,
  ``heuristic_weights``, ``skin_motion``, LBS) under the bones;
* a retarget result (``RESULT.npz`` from ``jaxanim retarget``, :mod:`._retarget_clip`) is two
  figures: the robot's bodies as orange sticks (from each body to its parent, not the world) and
  its source skeleton in blue beside it, shifted along the robot's +Y just clear of it; the
  robot's frame (Z up, metres) is turned into the scene's Y up by the rotation
  ``(x, y, z) -> (x, z, -y)``, so the robot still faces +X and its source stands at -Z;
* several clips (a retarget result counts as one) stand side by side along X, each shifted by a
  constant so the clips' X ranges over all their frames do not overlap (a gap of a third of the
  tallest figure between them);
* a ground grid at the lowest point of all clips.

The timeline runs at the first clip's frame rate over the longest clip; each clip shows its frame
nearest in time (clips of other frame rates stay aligned; one that has ended holds its last frame).
The control panel has the frame slider, a play checkbox, the playback rate in frames per second and
the time. FK of every frame is one batched call per clip, done before the server starts; playback
only sends the new points.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import ipaddress
import math
import re
import socket
import threading
from collections.abc import Sequence
from typing import Any

import numpy as np

from .._errors import JaxanimError
from ._common import _UI, _Clip, _clip_fk, _load, _num
from ._plot import _side
from ._render import _nice_step
from ._retarget_clip import (
    RetargetClip,
    is_retarget_file,
    load_retarget,
    retarget_scene,
)

__all__ = ["BONE_RGB", "Viewer", "add_view_parser", "build_viewer"]

# Bone colours (sRGB): the centre line is magenta, a colour the viser page itself never uses, so a
# screenshot test can find the skeleton by it.
BONE_RGB = {"left": (30, 100, 255), "right": (235, 30, 30), "center": (220, 0, 220)}
_JOINT_RGB = (30, 30, 30)
_MESH_RGB = (150, 180, 220)
_ROBOT_RGB, _SOURCE_RGB = (255, 127, 14), (31, 119, 180)  # matplotlib's tab:orange and tab:blue, as render's


@dataclasses.dataclass
class _ViewClip:
    name: str
    points: np.ndarray  # [frames, joints + end_sites, 3], shifted into place
    pairs: np.ndarray  # [bones, 2] point indices
    num_joints: int
    index: np.ndarray  # [timeline] the frame shown at each step of the timeline
    colors: np.ndarray  # [bones, 2, 3] uint8
    group: int  # the input it comes from: a group stands together (a robot and its source)
    bones: Any = None  # viser handles
    joints: Any = None
    label: Any = None
    mesh: Any = None
    vertices: np.ndarray | None = None  # [frames, V, 3], shifted
    label_positions: np.ndarray | None = None  # [frames, 3] above the head


@dataclasses.dataclass
class Viewer:
    """A running viewer (from :func:`build_viewer`).

    Attributes:
        server: the ``viser.ViserServer``.
        url: where to open it, ``http://host:port``.
        times: ``[steps]`` the timeline, seconds.
        frame, playing, fps, time: the GUI handles (frame slider, play checkbox, playback rate, time
            readout); assign ``frame.value`` to show a step.
    """

    server: Any
    url: str
    times: np.ndarray
    frame: Any
    playing: Any
    fps: Any
    time: Any
    clips: list[_ViewClip]
    _lock: threading.Lock = dataclasses.field(default_factory=threading.Lock)

    @property
    def num_steps(self) -> int:
        return len(self.times)

    def show(self, k: int) -> None:
        """Move every clip to step ``k`` of the timeline (what the frame slider does)."""
        k = int(min(max(k, 0), self.num_steps - 1))
        with self._lock, self.server.atomic():
            for c in self.clips:
                f = int(c.index[k])
                pts = c.points[f]
                c.bones.points = np.stack([pts[c.pairs[:, 0]], pts[c.pairs[:, 1]]], axis=1).astype(np.float32)
                c.joints.points = pts[: c.num_joints].astype(np.float32)
                c.label.position = tuple(float(x) for x in c.label_positions[f])
                if c.mesh is not None:
                    c.mesh.vertices = c.vertices[f].astype(np.float32)
            self.time.value = f"{self.times[k]:.2f} s"

    def run(self, stop: threading.Event | None = None) -> None:
        """The playback loop: while ``playing`` is ticked, advance one step every ``1 / fps`` seconds
        (looping); returns when ``stop`` is set (never without one)."""
        stop = stop or threading.Event()
        while not stop.is_set():
            if self.playing.value and self.num_steps > 1:
                self.frame.value = (int(self.frame.value) + 1) % self.num_steps
            stop.wait(1.0 / max(float(self.fps.value), 1e-3))

    def close(self) -> None:
        """Stop the server."""
        with contextlib.redirect_stdout(io.StringIO()):  # viser prints "Server stopped"
            self.server.stop()


def _import_viser():
    try:
        import viser
    except ImportError:
        raise JaxanimError("the viewer needs viser: install jaxanim[view] (pip install 'jaxanim[view]')") from None
    return viser


def _skinned(clip: _Clip, ui: _UI) -> tuple[np.ndarray, np.ndarray]:
    """``vertices [frames, V, 3]`` and ``faces [T, 3]`` of the capsule skin (LBS)."""
    from .. import skinning
    ui.progress(f"skinning the capsule mesh of {clip.label} ({clip.motion.num_frames} frames, LBS)")
    mesh = skinning.capsule_mesh(clip.skeleton)
    weights = skinning.heuristic_weights(clip.skeleton, mesh.vertices)
    v = np.asarray(skinning.skin_motion(clip.skeleton, clip.motion, mesh, weights, method="lbs"), np.float64)
    return v, np.asarray(mesh.faces, np.int64)


def _timing(c: _Clip | RetargetClip) -> tuple[int, float, float]:
    """(frames, frame time, fps) of a clip or a retarget result."""
    if isinstance(c, RetargetClip):
        return c.num_frames, c.frame_time, c.fps
    return c.motion.num_frames, float(c.motion.frame_time), float(c.motion.fps)


def _bone_colors(rgb: Sequence[tuple[int, int, int]]) -> np.ndarray:
    return np.array(rgb, np.uint8).reshape(-1, 1, 3).repeat(2, axis=1)


def _retarget_views(c: RetargetClip, index: np.ndarray, group: int) -> list[_ViewClip]:
    """The robot and its source beside it, turned from Z up to the scene's Y up."""
    scene = retarget_scene(c)
    pts = scene.points[..., [0, 2, 1]] * np.array([1.0, 1.0, -1.0])  # (x, y, z) -> (x, z, -y)
    R = scene.num_robot
    robot = _ViewClip(scene.robot_label, pts[:, :R], scene.sticks, R, index,
                      _bone_colors([_ROBOT_RGB] * len(scene.sticks)), group)
    source = _ViewClip(scene.source_label, pts[:, R:], scene.bones - R, pts.shape[1] - R, index,
                       _bone_colors([_SOURCE_RGB] * len(scene.bones)), group)
    return [robot, source]


def _check_host(host: str) -> None:
    """Refuse an address that cannot be listened on before any work (``999.1.1.1`` hung after
    "starting the viewer"): not an IP address nor a host name, or one that a socket cannot bind."""
    try:
        literal = ipaddress.ip_address(host)
    except ValueError:
        literal = None
        if re.fullmatch(r"[0-9.]+", host) or not re.fullmatch(r"[A-Za-z0-9.-]+", host):
            raise JaxanimError(f"--host {host}: not an IP address or a host name") from None
    family = socket.AF_INET6 if literal is not None and literal.version == 6 else socket.AF_INET
    try:
        with socket.socket(family) as sock:
            sock.bind((host, 0))
    except OSError as exc:
        raise JaxanimError(f"--host {host}: cannot listen on it: {exc.strerror or exc}") from None


def build_viewer(
    clips: Sequence[_Clip | RetargetClip],
    *,
    port: int = 8080,
    host: str = "127.0.0.1",
    mesh: bool = False,
    playing: bool = True,
    ui: _UI | None = None,
) -> Viewer:
    """Compute FK of the clips, start a viser server showing them at step 0, and return at once.

    Args:
        clips: the loaded clips (:func:`._common._load`) or retarget results
            (:func:`._retarget_clip.load_retarget`), placed left to right along X.
        port: the port to listen on (``0``: any free one; viser takes the next free one if taken).
        host: the address to listen on (``"0.0.0.0"`` for every interface).
        mesh: also show the skinned capsule mesh (:mod:`jaxanim.skinning`) of the BVH clips.
        playing: the play checkbox's initial state.
        ui: where progress goes (default: quiet).

    Returns:
        A :class:`Viewer`; :meth:`Viewer.close` stops the server.

    Raises:
        JaxanimError: viser is not installed, no clip, a ``host`` that cannot be listened on, a clip
            without frames or with non-finite positions, ``--mesh`` without :mod:`jaxanim.skinning`.
    """
    ui = ui or _UI(quiet=True)
    viser = _import_viser()
    if not clips:
        raise JaxanimError("no clip to view")
    _check_host(host)
    for c in clips:
        if _timing(c)[0] == 0:
            raise JaxanimError(f"{c.label} has no frames")
    ft0 = _timing(clips[0])[1]
    duration = max((n - 1) * ft for n, ft, _ in map(_timing, clips))
    times = np.arange(math.floor(duration / ft0 + 1e-6) + 1) * ft0

    views: list[_ViewClip] = []
    for i, c in enumerate(clips):
        n, ft, _ = _timing(c)
        index = np.clip(np.rint(times / ft).astype(np.int64), 0, n - 1)
        if isinstance(c, RetargetClip):
            views += _retarget_views(c, index, i)
            continue
        sk = c.skeleton
        fk = _clip_fk(c, ui).result
        pts = np.concatenate([np.asarray(fk.positions, np.float64), np.asarray(fk.end_site_positions, np.float64)],
                             axis=1)
        if not np.isfinite(pts).all():
            raise JaxanimError(f"{c.label}: the joint positions are not all finite; cannot show them")
        J = sk.num_joints
        bones = [(par, j) for j, par in enumerate(sk.parents) if par >= 0]
        bones += [(par, J + k) for k, par in enumerate(sk.end_site_parents)]
        sides = [_side(name) for name in sk.names]
        v = _ViewClip(c.path.name, pts, np.array(bones, np.int64).reshape(-1, 2), J, index,
                      _bone_colors([BONE_RGB[sides[a]] for a, _ in bones]), i)
        if mesh:
            v.vertices, faces = _skinned(c, ui)
            v.mesh = faces  # replaced by the handle below
        views.append(v)

    # side by side along X, with a gap of a third of the tallest figure
    def extent(v: _ViewClip) -> np.ndarray:
        allpts = v.points if v.vertices is None else np.concatenate([v.points, v.vertices], axis=1)
        return np.stack([allpts.reshape(-1, 3).min(axis=0), allpts.reshape(-1, 3).max(axis=0)])

    groups = sorted({v.group for v in views})
    boxes = []
    for g in groups:
        b = np.stack([extent(v) for v in views if v.group == g])
        boxes.append(np.stack([b[:, 0].min(axis=0), b[:, 1].max(axis=0)]))
    height = max(float(b[1, 1] - b[0, 1]) for b in boxes) or 1.0
    right = None
    for g, b in zip(groups, boxes):
        shift = 0.0 if right is None else right + height / 3.0 - float(b[0, 0])
        for v in views:
            if v.group == g:
                v.points = v.points + np.array([shift, 0.0, 0.0])
                if v.vertices is not None:
                    v.vertices = v.vertices + np.array([shift, 0.0, 0.0])
        b += np.array([shift, 0.0, 0.0])
        right = float(b[1, 0])
    for v in views:  # the name above the root, a little higher than the highest joint
        v.label_positions = v.points[:, 0] * np.array([1.0, 0.0, 1.0])
        v.label_positions[:, 1] = v.points[:, : v.num_joints, 1].max(axis=1) + 0.12 * height
    lo = np.min([b[0] for b in boxes], axis=0)
    hi = np.max([b[1] for b in boxes], axis=0)

    ui.progress(f"starting the viewer on {host}:{port}")
    with contextlib.redirect_stdout(io.StringIO()):  # viser's banner; the command prints the URL
        server = viser.ViserServer(host=host, port=port, verbose=False)
    scene = server.scene
    scene.set_up_direction("+y")
    server.gui.configure_theme(control_layout="floating", show_share_button=False)
    center = 0.5 * (lo + hi)
    span = float(max(hi[0] - lo[0], hi[2] - lo[2])) + height
    step = _nice_step(span)
    scene.add_grid("/ground", width=math.ceil(span / step) * step, height=math.ceil(span / step) * step,
                   plane="xz", cell_size=step, section_size=5 * step,
                   position=(float(center[0]), float(lo[1]), float(center[2])))
    thickness, point_size = 0.025 * height, 0.03 * height
    for i, v in enumerate(views):
        pts = v.points[0]
        if v.vertices is not None:
            v.mesh = scene.add_mesh_simple(f"/clip{i}/mesh", v.vertices[0].astype(np.float32), v.mesh,
                                           color=_MESH_RGB, opacity=0.6, side="double")
        v.bones = scene.add_line_segments(
            f"/clip{i}/bones", np.stack([pts[v.pairs[:, 0]], pts[v.pairs[:, 1]]], axis=1).astype(np.float32),
            v.colors, thickness=thickness)
        v.joints = scene.add_point_cloud(f"/clip{i}/joints", pts[: v.num_joints].astype(np.float32), _JOINT_RGB,
                                         point_size=point_size, point_shape="circle", precision="float32",
                                         point_shading="flat")
        v.label = scene.add_label(f"/clip{i}/name", v.name, position=(0.0, 0.0, 0.0))

    # the camera: looking at the middle of everything the clips cover, from the side and front (+X, +Z)
    # and a little above, far enough to see it all (orbit and zoom with the mouse)
    look = np.array([center[0], lo[1] + 0.5 * height, center[2]])
    direction = np.array([0.75, 0.3, 0.6]) / np.linalg.norm([0.75, 0.3, 0.6])
    distance = 0.6 * float(max(hi[0] - lo[0], hi[2] - lo[2])) + 1.6 * height
    server.initial_camera.look_at = tuple(float(x) for x in look)
    server.initial_camera.position = tuple(float(x) for x in look + distance * direction)
    server.initial_camera.up = (0.0, 1.0, 0.0)

    gui = server.gui
    fps0 = _timing(clips[0])[2]
    frame = gui.add_slider("frame", min=0, max=max(len(times) - 1, 1), step=1, initial_value=0,
                           disabled=len(times) < 2)
    play = gui.add_checkbox("play", initial_value=playing)
    fps = gui.add_slider("fps", min=1.0, max=max(120.0, fps0), step=1.0, initial_value=round(fps0))
    time_text = gui.add_text("time", initial_value="0.00 s", disabled=True)
    names = ", ".join(v.name for v in views)
    gui.add_markdown(f"{len(views)} clip{'s' if len(views) > 1 else ''}: {names}; "
                     f"{len(times)} frames at {_num(fps0)} fps")
    viewer = Viewer(server, f"http://{'localhost' if host in ('0.0.0.0', '::') else host}:{server.get_port()}",
                    times, frame, play, fps, time_text, views)
    frame.on_update(lambda _: viewer.show(int(frame.value)))
    viewer.show(0)
    return viewer


def _cmd_view(args: argparse.Namespace, ui: _UI) -> int:
    if not 0 <= args.port <= 65535:
        raise JaxanimError(f"--port {args.port}: expected 0 to 65535")
    _import_viser()
    clips = [load_retarget(f) if is_retarget_file(f) else _load(f, ui, args.dtype) for f in (args.files or [None])]
    viewer = build_viewer(clips, port=args.port, host=args.host, mesh=args.mesh, ui=ui)
    ui.result(f"viewing {', '.join(c.label for c in clips)} at {viewer.url} (Ctrl-C stops)")
    try:
        viewer.run()
    except KeyboardInterrupt:
        pass
    finally:
        viewer.close()
    return 0


def add_view_parser(sub, common) -> None:
    p = sub.add_parser("view", parents=[common], help="interactive 3-D viewer in the browser (viser)",
                       description="Serve an interactive 3-D view of one or more clips (jaxanim[view], viser) and "
                                   "print its address: the skeletons side by side, a ground grid, a timeline with a "
                                   "frame slider, play/pause and the playback rate; --mesh adds the skinned capsule "
                                   "mesh. A retarget result (RESULT.npz, from jaxanim retarget) shows the robot's "
                                   "sticks beside its source skeleton. Runs until Ctrl-C.")
    p.add_argument("files", nargs="*", metavar="FILE.bvh|RESULT.npz",
                   help="BVH files or retarget results (default: the shipped walk clip)")
    p.add_argument("--port", "-p", type=int, default=8080, metavar="P",
                   help="port (default 8080; the next free one if taken; 0: any free one)")
    p.add_argument("--host", default="127.0.0.1", metavar="ADDR",
                   help="address to listen on (default 127.0.0.1, this machine only; 0.0.0.0 for every interface)")
    p.add_argument("--mesh", action="store_true", help="also show the skinned capsule mesh (jaxanim.skinning, LBS)")
    p.set_defaults(func=_cmd_view)
