"""``jaxanim render`` and ``jaxanim view`` of a retarget result (.npz): the robot beside its source
skeleton, from a synthetic result (a 3-body chain and a 5-joint source walking forward along +X, Z
up), read back with Pillow; the robot drawn from its collision geometry (the result's geometry keys)
where MuJoCo's ``mj_kinematics`` puts the geoms, and as sticks without those keys; the errors for bad
results; the viewer's scene.

Every render is small (a few frames at 100 x 100 pixels) and runs in-process through ``main([...])``
or :func:`render_retarget`; nothing here runs JAX (the geometry's reference is MuJoCo's).
"""

from __future__ import annotations

import pathlib

import numpy as np
import pytest

pytest.importorskip("PIL", reason="rendering needs Pillow (it comes with matplotlib: jaxanim[plot])")
pytest.importorskip("matplotlib", reason="rendering needs matplotlib (jaxanim[plot])")

from jaxanim._errors import JaxanimError
from jaxanim.app._render import render_retarget
from jaxanim.app._retarget_clip import load_retarget, retarget_scene, source_shift

from .test_render import _frames, _run

_SIZE = 100  # pixels
_T = 10  # frames
_FPS = 30.0
# matplotlib's tab:orange (the robot) and tab:blue (the source), after the GIF palette
_ROBOT_RGB, _SOURCE_RGB = (255, 127, 14), (31, 119, 180)
_COLOUR_TOL = 40  # per channel
_MIN_PIXELS = 15  # of each figure's colour, at 100 x 100 pixels


def _result(T: int = _T) -> dict[str, np.ndarray]:
    """A retarget result: world + a 3-body chain (pelvis, knee, foot) and a 5-joint source (hips, spine,
    head, thigh, foot) at the same place, walking forward along +X at 1 m/s, the feet swinging."""
    t = np.arange(T) / _FPS
    x = 1.0 * t
    swing = 0.15 * np.sin(2 * np.pi * t)
    z = np.zeros(T)
    body = np.stack([
        np.stack([z, z, z], -1),  # world, at the origin
        np.stack([x, z, z + 0.9], -1),  # pelvis
        np.stack([x + 0.5 * swing, z, z + 0.5], -1),  # knee
        np.stack([x + swing, z, z + 0.08], -1),  # foot
    ], axis=1)
    source = np.stack([
        np.stack([x, z, z + 1.0], -1),  # Hips
        np.stack([x, z, z + 1.35], -1),  # Spine
        np.stack([x, z, z + 1.65], -1),  # Head
        np.stack([x, z + 0.1, z + 0.95], -1),  # LeftUpLeg
        np.stack([x + swing, z + 0.1, z + 0.05], -1),  # LeftFoot
    ], axis=1)
    F = 2
    contacts = np.zeros((T, F), bool)
    contacts[: T // 2, 0] = True
    contacts[T // 2:, 1] = True
    return {
        "qpos": np.zeros((T, 9)), "fps": np.array(_FPS),
        "joint_names": np.array(["root", "hip", "knee"]),
        "body_names": np.array(["world", "pelvis", "shin", "foot"]),
        "body_parents": np.array([-1, 0, 1, 2]),
        "body_positions": body,
        "source_positions": source,
        "source_parents": np.array([-1, 0, 1, 0, 3]),
        "source_names": np.array(["Hips", "Spine", "Head", "LeftUpLeg", "LeftFoot"]),
        "feet": np.array(["foot", "LeftFoot"]),
        "contacts": contacts,
        "foot_slide": np.zeros((T, F)), "penetration": np.zeros((T, F)), "position_error": np.zeros((T, 3)),
        "robot": np.array("robots/chain.xml"), "source": np.array("clips/walk.bvh"), "map": np.array("chain.json"),
    }


def _with_geometry(d: dict) -> dict:
    """The result with the robot's geometry keys: the pelvis a sphere, a box (the torso), an ellipsoid (the
    head) and a mesh (its points); the shin a capsule (the thigh, above its origin) and a cylinder (below);
    the foot no geom, only a sole's four corners on the ground. The bodies keep the world's axes."""
    T, B = d["body_positions"].shape[:2]
    return {
        **d, "body_xmat": np.tile(np.eye(3), (T, B, 1, 1)),
        "geom_body": np.array([1, 1, 1, 1, 2, 2]),
        "geom_type": np.array(["sphere", "box", "ellipsoid", "mesh", "capsule", "cylinder"]),
        "geom_size": np.array([[0.1, 0, 0], [0.08, 0.12, 0.15], [0.07, 0.08, 0.1], [0.05, 0.05, 0.05],
                               [0.05, 0.2, 0], [0.04, 0.2, 0]]),
        "geom_pos": np.array([[0, 0, 0], [0, 0, 0.3], [0, 0, 0.6], [0, 0, 0], [0, 0, 0.2], [0, 0, -0.2]]),
        "geom_quat": np.tile([1.0, 0, 0, 0], (6, 1)),
        "point_body": np.array([1, 1, 3, 3, 3, 3]),
        "point_pos": np.array([[0.05, 0, 0], [-0.05, 0, 0], [-0.1, -0.05, -0.08], [-0.1, 0.05, -0.08],
                               [0.1, -0.05, -0.08], [0.1, 0.05, -0.08]]),
    }


def _save(path: pathlib.Path, arrays: dict) -> pathlib.Path:
    with open(path, "wb") as fh:
        np.savez(fh, **arrays)
    return path


@pytest.fixture(scope="module")
def result_npz(tmp_path_factory) -> pathlib.Path:
    return _save(tmp_path_factory.mktemp("retarget") / "walk_chain.npz", _result())


def _mask(img: np.ndarray, rgb) -> np.ndarray:
    return np.abs(img - np.array(rgb)).max(axis=-1) <= _COLOUR_TOL


def _assert_side_by_side(img: np.ndarray, where: str) -> None:
    """Both figures drawn, upright (taller than wide on screen) and apart (the source on the right)."""
    cols = {}
    for name, rgb in (("robot", _ROBOT_RGB), ("source", _SOURCE_RGB)):
        ys, xs = np.nonzero(_mask(img, rgb))
        assert len(xs) >= _MIN_PIXELS, f"{where}: {len(xs)} pixels of the {name} colour {rgb}"
        assert np.ptp(ys) > np.ptp(xs), f"{where}: the {name} is {np.ptp(xs)} px wide, {np.ptp(ys)} px tall: not upright"
        cols[name] = np.median(xs)
    assert cols["source"] - cols["robot"] > 0.1 * img.shape[1], f"{where}: not side by side: {cols}"


def test_render_retarget_npz_through_the_cli(tmp_path, capsys, result_npz):
    out = tmp_path / "robot.gif"
    code, stdout, err = _run(capsys, "render", result_npz, "--size", _SIZE, "--out", out)
    assert code == 0, err
    assert f"wrote {out}: {_T} frames at 30 fps" in stdout and "chain.xml beside walk.bvh" in stdout
    assert "Traceback" not in err
    frames = _frames(out)
    assert len(frames) == _T and frames[0].shape == (_SIZE, _SIZE, 3)
    for k in (0, _T - 1):
        _assert_side_by_side(frames[k], f"frame {k}")
    assert np.abs(frames[0] - frames[_T - 1]).max() > 0, "the figures do not move"


def test_render_retarget_frames_fps_and_camera(tmp_path, capsys, result_npz):
    """--frames 2:8 at --fps 15 of a 30 fps result: t = 2/30 .. 7/30 s every 1/15 s -> 3 frames."""
    out = tmp_path / "part.gif"
    code, stdout, err = _run(capsys, "render", result_npz, "--frames", "2:8", "--fps", "15", "--camera", "fixed",
                             "--size", _SIZE, "--out", out)
    assert code == 0, err
    assert "3 frames at 15 fps" in stdout
    assert len(_frames(out)) == 3


def test_render_retarget_from_a_dict(tmp_path):
    data = _result()
    before = {k: np.copy(v) for k, v in data.items()}
    out = tmp_path / "dict.gif"
    info = render_retarget(data, out, fps=10.0, size=_SIZE)
    frames = _frames(out)
    assert info.frames == len(frames) == 4  # t = 0, 0.1, 0.2, 0.3 s of 0 .. 0.3 s
    _assert_side_by_side(frames[1], "frame 1")
    for k, v in before.items():
        np.testing.assert_array_equal(data[k], v, err_msg=f"field: {k} was modified")


def test_scene_layout():
    clip = load_retarget(_result())
    scene = retarget_scene(clip)
    R = 3
    assert scene.points.shape == (_T, R + 5, 3) and scene.num_robot == R
    assert scene.sticks.tolist() == [[1, 0], [2, 1]]  # no stick to the world
    assert scene.bones.tolist() == [[R + 1, R], [R + 2, R + 1], [R + 3, R], [R + 4, R + 3]]
    assert scene.feet.tolist() == [2, R + 4]  # "foot" is a robot body, "LeftFoot" a source joint
    shift = source_shift(clip)
    assert shift == scene.shift > 0
    gap = (scene.points[:, R:, 1].min(axis=1) - scene.points[:, :R, 1].max(axis=1)).min()
    assert gap >= 0.1, f"source only {gap:.3f} m beside the robot"
    np.testing.assert_allclose(scene.points[:, R:] - clip.source_positions, np.broadcast_to([0, shift, 0], (_T, 5, 3)),
                               err_msg="field: source shifted along +Y only")
    # a source already standing far to the +Y side stays where it is
    far = _result()
    far["source_positions"] = far["source_positions"] + np.array([0.0, 2.0, 0.0])
    assert source_shift(load_retarget(far)) == 0.0


def test_render_retarget_from_its_geometry(tmp_path, capsys):
    """With the geometry keys the robot is its geoms (wider than its sticks), beside its source."""
    data = _with_geometry(_result())
    clip = load_retarget(data)
    assert clip.geometry is not None and clip.geometry.geom_type[4] == "capsule" and clip.body_xmat.shape == (_T, 4, 3, 3)
    path = _save(tmp_path / "geoms.npz", data)
    code, _, err = _run(capsys, "render", path, "--size", _SIZE, "--out", tmp_path / "geoms.gif")
    assert code == 0, err
    solid = _frames(tmp_path / "geoms.gif")
    code, _, err = _run(capsys, "render", _save(tmp_path / "sticks.npz", _result()), "--size", _SIZE, "--out",
                        tmp_path / "sticks.gif")
    assert code == 0, err
    sticks = _frames(tmp_path / "sticks.gif")
    for k in (0, _T - 1):
        _assert_side_by_side(solid[k], f"frame {k}")
        wide, thin = (_orange(f[k]).sum() for f in (solid, sticks))
        assert wide > 2 * thin, f"frame {k}: {wide} robot pixels from its geometry, {thin} as sticks"


def _orange(img: np.ndarray) -> np.ndarray:
    """The robot's colour in any shade (the boxes are shaded, the outlines darker)."""
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    return (r - b > 90) & (r > g) & (g > b)


def test_shapes_of_a_synthetic_robot():
    """Each kind of geom where it belongs (the bodies keep the world's axes): the capsule's and the cylinder's
    end centres, the sphere's centre, a box's 6 faces, an ellipsoid's 3 ellipses, the mesh's points as dots,
    the sole's outline (4 edges) around its corners."""
    from jaxanim.app._robot_draw import robot_shapes

    clip = load_retarget(_with_geometry(_result()))
    xpos = clip.body_positions[3]
    s = robot_shapes(clip.geometry, xpos, clip.body_xmat[3])
    up = np.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose(s.capsules, [[xpos[2], xpos[2] + 0.4 * up]], err_msg="field: capsules")
    np.testing.assert_allclose(s.cylinders, [[xpos[2] - 0.4 * up, xpos[2]]], err_msg="field: cylinders")
    assert s.capsule_radius.tolist() == [0.05] and s.cylinder_radius.tolist() == [0.04]
    np.testing.assert_allclose(s.spheres, [xpos[1]], err_msg="field: spheres")
    assert s.faces.shape == (6, 4, 3) and s.face_geoms.tolist() == [1] * 6
    np.testing.assert_allclose(s.faces.reshape(-1, 3).min(axis=0), xpos[1] + [-0.08, -0.12, 0.15],
                               err_msg="field: box faces")
    np.testing.assert_allclose(s.dots, xpos[1] + [[0.05, 0, 0], [-0.05, 0, 0]], err_msg="field: mesh dots")
    rings, sole = s.lines[:-4], s.lines[-4:]
    assert len(rings) == 3 * 24
    np.testing.assert_allclose(np.abs(rings.reshape(-1, 3) - xpos[1] - 0.6 * up).max(axis=0), [0.07, 0.08, 0.1],
                               err_msg="field: ellipsoid")
    np.testing.assert_allclose(sole[:, 1], np.roll(sole[:, 0], -1, axis=0), err_msg="field: the sole is closed")
    corners = xpos[3] + clip.geometry.point_pos[2:]
    assert sorted(map(tuple, sole[:, 0].round(12))) == sorted(map(tuple, corners.round(12))), "field: sole corners"
    assert np.abs(sole[:, 0, 2]).max() < 1e-12, "the sole is on the ground"


_MJ_FRAMES = 3


def _mujoco_result(model, mujoco, robot) -> tuple[dict, np.ndarray, np.ndarray]:
    """A result of ``_MJ_FRAMES`` random poses of ``model`` as MuJoCo's ``mj_kinematics`` places it (its geometry
    from ``robot``: the Robot's fields as ``jaxanim retarget`` writes them), and MuJoCo's ``geom_xpos [T, G, 3]``,
    ``geom_xmat [T, G, 3, 3]`` of the robot's geoms."""
    rng = np.random.default_rng(3)
    data = mujoco.MjData(model)
    keep = [g for g in range(model.ngeom) if model.geom_bodyid[g] > 0 and model.geom_type[g] != 0]
    xpos, xmat, gpos, gmat = [], [], [], []
    for _ in range(_MJ_FRAMES):
        data.qpos[:] = model.qpos0
        data.qpos[7:] += rng.uniform(-0.5, 0.5, model.nq - 7)
        data.qpos[:3] += rng.uniform(-0.3, 0.3, 3)
        data.qpos[3:7] = rng.normal(size=4) / 4 + [1, 0, 0, 0]
        data.qpos[3:7] /= np.linalg.norm(data.qpos[3:7])
        mujoco.mj_kinematics(model, data)
        xpos.append(data.xpos.copy())
        xmat.append(data.xmat.reshape(-1, 3, 3).copy())
        gpos.append(data.geom_xpos[keep].copy())
        gmat.append(data.geom_xmat[keep].reshape(-1, 3, 3).copy())
    d = _result(_MJ_FRAMES)
    B = model.nbody
    d.update({
        "body_names": np.array(robot.body_names), "body_parents": np.array(robot.body_parents),
        "body_positions": np.array(xpos), "body_xmat": np.array(xmat), "feet": np.array([robot.body_names[-1]]),
        "contacts": np.ones((_MJ_FRAMES, 1), bool), "geom_body": np.array(robot.geom_bodies),
        "geom_type": np.array(robot.geom_types), "point_body": np.array(robot.point_bodies),
        **{k: np.asarray(getattr(robot, k)) for k in ("geom_size", "geom_pos", "geom_quat", "point_pos")},
    })
    assert d["body_positions"].shape[1] == B
    return d, np.array(gpos), np.array(gmat)


@pytest.mark.parametrize("key", ["humanoid", "g1"])
def test_the_drawing_puts_the_geoms_where_mujoco_does(key):
    """The shipped humanoid (capsules, boxes, spheres) and the G1 (spheres, cylinders) at random poses: what
    the render draws (capsule and cylinder end centres, sphere centres, box faces), read from its artist, is
    where MuJoCo's ``geom_xpos`` / ``geom_xmat`` put the geoms; a capsule is drawn as wide as it is."""
    mujoco = pytest.importorskip("mujoco", reason="the reference is MuJoCo (jaxanim[robots])")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from jaxanim import robots
    from jaxanim.app._render import _RetargetArtist
    from jaxanim.app._robot_draw import pixels_per_metre

    from .conftest import shared_data_dir

    path = robots.default_robot_path() if key == "humanoid" else shared_data_dir() / "robots/unitree_g1/g1.xml"
    model = mujoco.MjModel.from_xml_path(str(path))
    robot = robots.load_robot(path)
    data, gpos, gmat = _mujoco_result(model, mujoco, robot)
    scene = retarget_scene(load_retarget(data))
    fig = Figure(figsize=(2, 2), dpi=100)
    FigureCanvasAgg(fig)
    artist = _RetargetArtist(fig.add_subplot(1, 1, 1, projection="3d"), "t", scene, np.arange(_MJ_FRAMES),
                             "fixed", 200)
    drawn = []
    update = artist.robot.update
    artist.robot.update = lambda *a: drawn.append(update(*a)) or drawn[-1]
    size = np.asarray(robot.geom_size)
    for f in range(_MJ_FRAMES):
        artist.update(f, 0.0)
        s = drawn[-1]
        for kind, ends, geoms in (("capsule", s.capsules, s.capsule_geoms), ("cylinder", s.cylinders, s.cylinder_geoms)):
            half = gmat[f][geoms, :, 2] * size[geoms, 1:2]
            expected = np.stack([gpos[f][geoms] - half, gpos[f][geoms] + half], axis=1)
            np.testing.assert_allclose(ends, expected, atol=1e-9, err_msg=f"field: {kind} ends, frame {f}")
        np.testing.assert_allclose(s.spheres, gpos[f][s.sphere_geoms], atol=1e-9, err_msg=f"field: spheres, frame {f}")
        for g in np.unique(s.face_geoms):  # every corner of every face at (+-x, +-y, +-z) in the geom's frame
            local = (s.faces[s.face_geoms == g].reshape(-1, 3) - gpos[f][g]) @ gmat[f][g]
            np.testing.assert_allclose(np.abs(local), np.broadcast_to(size[g], local.shape), atol=1e-9,
                                       err_msg=f"field: box {g} corners, frame {f}")
            assert len(np.unique(np.sign(local).round(), axis=0)) == 8, f"box {g}: not all 8 corners"
    assert len(drawn[-1].capsules) + len(drawn[-1].cylinders) + len(drawn[-1].spheres) > 0
    if len(drawn[-1].capsules):  # as wide as the capsule in the view (its outline a little wider)
        ppm = pixels_per_metre(artist.ax, scene.points[-1, 0])
        fill = artist.robot.capsules[1].get_linewidths()
        order = np.argsort(drawn[-1].capsules.mean(axis=1) @ _eye(artist.ax))
        np.testing.assert_allclose(fill, 2 * drawn[-1].capsule_radius[order] * ppm * 72 / fig.dpi,
                                   err_msg="field: capsule widths")


def _eye(ax) -> np.ndarray:
    e, a = np.radians(ax.elev), np.radians(ax.azim)
    return np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])


def test_an_old_result_is_drawn_as_sticks():
    """A result without the geometry keys (written before them) has no geometry; its robot is thick sticks."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from jaxanim.app._render import _RetargetArtist

    clip = load_retarget(_result())
    assert clip.geometry is None and clip.body_xmat is None
    fig = Figure(figsize=(1, 1))
    FigureCanvasAgg(fig)
    artist = _RetargetArtist(fig.add_subplot(1, 1, 1, projection="3d"), "t", retarget_scene(clip), np.arange(_T),
                             "follow", _SIZE)
    artist.update(0, 0.0)
    assert artist.robot is None and artist.sticks.get_linewidths()[0] == 3.5


def _without(key):
    def edit(d):
        del d[key]
    return edit


def _nan_source(d):
    d["source_positions"][4, 2, 0] = np.nan


def _short_source(d):
    d["source_positions"] = d["source_positions"][:-1]


def _short_qpos(d):
    d["qpos"] = d["qpos"][:-1]


def _bad_parent(d):
    d["body_parents"] = np.array([-1, 0, 3, 2])


def _flat_bodies(d):
    d["body_positions"] = d["body_positions"][..., :2]


def _no_feet(d):
    del d["feet"]


def _geometry(change):
    def edit(d):
        d.update(_with_geometry(d))
        change(d)
    return edit


def _no_geom_pos(d):
    del d["geom_pos"]


def _cone(d):
    d["geom_type"] = np.array(["cone", *d["geom_type"][1:]])


def _on_the_world(d):
    d["geom_body"] = np.array([0, *d["geom_body"][1:]])


def _short_xmat(d):
    d["body_xmat"] = d["body_xmat"][:-1]


def _nan_size(d):
    d["geom_size"][4, 1] = np.nan


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (_without("body_positions"), "not a retarget result: missing key 'body_positions'"),
        (_without("fps"), "missing key 'fps'"),
        (_nan_source, "key 'source_positions': not all finite (the first at frame 4, index 2"),
        (_short_source, ("key 'source_positions': expected shape (T, J, 3) = (10, 5, 3) with T = 10 frames as in "
                         "'body_positions', got (9, 5, 3)")),
        (_short_qpos, "key 'qpos': expected shape (T, nq) = (10, nq) with T = 10 frames"),
        (_bad_parent, "key 'body_parents': entry 2 is 3: expected -1 (a root) or a parent index below 2"),
        (_flat_bodies, "key 'body_positions': expected shape (T, B, 3) = (T, 4, 3), got (10, 4, 2)"),
        (_no_feet, "key 'feet' is missing: 'contacts' needs it"),
        (_geometry(_no_geom_pos), "key 'geom_pos' is missing: 'body_xmat' needs it (the robot's geometry is "),
        (_geometry(_cone), "key 'geom_type': unknown geom types ['cone']; valid: ['sphere', 'capsule', "),
        (_geometry(_on_the_world), "key 'geom_body': entry 0 is 0: expected a body index in [1, 4) (not the world)"),
        (_geometry(_short_xmat), "key 'body_xmat': expected shape (T, B, 3, 3) = (10, 4, 3, 3), got (9, 4, 3, 3)"),
        (_geometry(_nan_size), "key 'geom_size': not all finite (the first at index (4, 1))"),
    ],
    ids=["missing-body-positions", "missing-fps", "nan-source", "mismatched-T", "mismatched-qpos", "parents",
         "shape", "contacts-without-feet", "geometry-incomplete", "geom-type", "geom-on-the-world", "xmat-shape",
         "nan-geom-size"],
)
def test_bad_result_names_the_file_and_the_key(tmp_path, capsys, edit, message):
    data = _result()
    edit(data)
    with pytest.raises(JaxanimError, match="^<mapping>: ") as exc:
        render_retarget(data, tmp_path / "x.gif", size=_SIZE)
    assert message in str(exc.value)
    path = _save(tmp_path / "bad.npz", data)
    code, _, err = _run(capsys, "render", path, "--out", tmp_path / "x.gif")
    assert code == 2, err
    assert err.strip().splitlines()[-1] == f"error: {path}: {str(exc.value).removeprefix('<mapping>: ')}"
    assert "Traceback" not in err
    assert not (tmp_path / "x.gif").exists()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--mesh"], "--mesh: not with a retarget result"),
        (["--frames", "0:11"], "--frames 0:11: expected A:B with 0 <= A < B <= 10"),
        (["--out", "x.avi"], "unknown output extension '.avi'"),
    ],
    ids=["mesh", "frames", "ext"],
)
def test_render_retarget_bad_flags(tmp_path, capsys, monkeypatch, result_npz, argv, message):
    monkeypatch.chdir(tmp_path)
    code, _, err = _run(capsys, "render", result_npz, *(argv if "--out" in argv else [*argv, "--out", "x.gif"]))
    assert code == 2 and message in err, err
    assert not list(tmp_path.glob("x.*"))


def test_render_not_an_npz(tmp_path, capsys):
    bad = tmp_path / "text.npz"
    bad.write_text("hello")
    code, _, err = _run(capsys, "render", bad, "--out", tmp_path / "x.gif")
    assert code == 2 and f"error: {bad}: not an .npz archive" in err, err
    code, _, err = _run(capsys, "render", tmp_path / "missing.npz", "--out", tmp_path / "x.gif")
    assert code == 2 and "missing.npz: cannot read the file" in err, err
    data = _result()
    data["body_names"] = data["body_names"].astype(object)
    pickled = _save(tmp_path / "pickled.npz", data)
    code, _, err = _run(capsys, "render", pickled, "--out", tmp_path / "x.gif")
    assert code == 2 and f"error: {pickled}: key 'body_names': an object array" in err, err


# ------------------------------------------------------------------------------------------------
# The viewer
# ------------------------------------------------------------------------------------------------


def test_viewer_of_a_retarget_result(result_npz):
    pytest.importorskip("viser", reason="the viewer needs viser (jaxanim[view])")
    from jaxanim.app._view import build_viewer

    v = build_viewer([load_retarget(result_npz)], port=0, playing=False)
    try:
        robot, source = v.clips
        assert v.num_steps == _T and v.fps.value == 30
        assert robot.bones.points.shape == (2, 2, 3) and robot.joints.points.shape == (3, 3)
        assert source.bones.points.shape == (4, 2, 3) and source.joints.points.shape == (5, 3)
        # Y up in the viewer: the robot's z is the viewer's y, its +Y the viewer's -Z (a rotation)
        np.testing.assert_allclose(robot.points[..., 1], load_retarget(result_npz).body_positions[:, 1:, 2],
                                   err_msg="field: robot height")
        assert source.points[..., 1].max() > 1.6  # the head, upright
        # beside: the source to the robot's +Y side (the viewer's -Z) in every frame, not moved along X
        assert (source.points[..., 2].max(axis=1) < robot.points[..., 2].min(axis=1)).all()
        np.testing.assert_allclose(source.points[:, 0, 0], robot.points[:, 0, 0], err_msg="field: x of the roots")
        start = robot.bones.points.copy()
        v.frame.value = _T - 1
        assert np.abs(robot.bones.points - start).max() > 0.2, "the robot did not move"
        np.testing.assert_allclose(source.joints.points, source.points[_T - 1], atol=1e-6,
                                   err_msg="field: source joints at the last step")
    finally:
        v.close()


def test_view_command_takes_an_npz(capsys, monkeypatch, result_npz):
    pytest.importorskip("viser", reason="the viewer needs viser (jaxanim[view])")
    from jaxanim.app._view import Viewer

    def interrupted(self, stop=None):
        raise KeyboardInterrupt

    monkeypatch.setattr(Viewer, "run", interrupted)
    code, out, err = _run(capsys, "view", result_npz, "--port", "0")
    assert code == 0, err
    assert f"viewing {result_npz} at http://127.0.0.1:" in out
    bad = result_npz.parent / "bad_view.npz"
    data = _result()
    del data["source_names"]
    _save(bad, data)
    code, _, err = _run(capsys, "view", bad, "--port", "0")
    assert code == 2 and f"error: {bad}: not a retarget result: missing key 'source_names'" in err, err
