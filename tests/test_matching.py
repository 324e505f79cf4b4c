"""Motion matching (jaxanim.matching; ``jaxanim match``), issue 14 part 2.

One database for the file: the shipped walk and its mirror image (240 frames, 150 searchable). One
controller shape is compiled for it (10 s = 301 frames, a 2-key input) and shared by the walk test
and the CLI; the vmap test compiles the batched program once. Independent references: the search
against a NumPy brute force (and ties to the lowest index); the features of a few frames against a
NumPy forward kinematics and finite differences written here.
"""

from __future__ import annotations

import json
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxanim
from jaxanim import matching
from jaxanim.app import _cli as cli
from jaxanim.kinematics._contacts import clip_positions

SECONDS = 10.0
FRAMES = 301  # 10 s at 30 fps
_ATOL_FEATURES = 1e-9


@pytest.fixture(scope="module")
def walk():
    skel, motion = jaxanim.read_bvh(jaxanim.default_clip_path())[:2]
    return skel, motion


@pytest.fixture(scope="module")
def db(walk):
    skel, motion = walk
    return matching.build_database([motion], skel, mirror=True)


def _constant(speed: float, yaw: float) -> matching.ControlInput:
    v = speed * np.array([np.sin(yaw), np.cos(yaw)])
    return matching.control_input([0.0, SECONDS], [v, v])


@pytest.fixture(scope="module")
def straight(db):
    return matching.motion_matching(db, _constant(1.2, 0.4), FRAMES)


# --- the search --------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def batched_search():
    return jax.jit(jax.vmap(lambda d, q: matching.search(d, q, chunk=64), in_axes=(None, 0)))


def _brute(features, searchable, queries):
    d = ((queries[:, None, :] - features[None]) ** 2).sum(-1)
    d[:, ~searchable] = np.inf
    return d


def test_search_equals_numpy_brute_force(db, batched_search):
    X = np.asarray(db.features)
    ok = np.asarray(db.searchable)
    rng = np.random.default_rng(0)
    rows = rng.integers(0, X.shape[0], 40)
    queries = np.concatenate([X[rows] + 0.3 * rng.standard_normal((40, X.shape[1])),
                              3.0 * rng.standard_normal((24, X.shape[1]))])
    res = batched_search(db, jnp.asarray(queries))
    res_walk_distance = np.asarray(res.distance)
    d = _brute(X, ok, queries)
    got = np.asarray(res.index)
    best = d.min(1)
    # the returned row is at the minimum distance (to round-off: the periodic walk repeats its cycle,
    # so rows a cycle apart tie to ~1e-10) ...
    np.testing.assert_allclose(d[np.arange(len(got)), got], best, rtol=1e-9, atol=1e-9, err_msg="distance of the row")
    np.testing.assert_allclose(np.asarray(res.distance), best, rtol=1e-9, atol=1e-9, err_msg="distance")
    # ... and is numpy's argmin wherever the runner-up is clearly farther
    second = np.sort(d, axis=1)[:, 1]
    clear = second > best * (1 + 1e-6) + 1e-9
    assert clear.sum() >= 10
    np.testing.assert_array_equal(got[clear], d.argmin(1)[clear], err_msg="index")
    assert ok[got].all()
    # random features (no near-ties), same shapes: exactly numpy's argmin
    R = rng.standard_normal(X.shape)
    res = batched_search(eqx_replace(db, R), jnp.asarray(queries))
    np.testing.assert_array_equal(np.asarray(res.index), _brute(R, ok, queries).argmin(1), err_msg="index, random")
    # vmap equals a loop of single searches
    for k in (0, 9, 45):
        one = matching.search(db, jnp.asarray(queries[k]), chunk=64)
        assert int(one.index) == int(got[k]), f"query {k}"
        np.testing.assert_allclose(float(one.distance), float(res_walk_distance[k]), rtol=1e-12)


def test_search_float32(walk, db):
    skel, motion = walk
    db32 = matching.build_database([motion], skel, mirror=True, dtype=jnp.float32)
    assert db32.features.dtype == jnp.float32
    X = np.asarray(db.features)
    ok = np.asarray(db.searchable)
    rng = np.random.default_rng(1)
    queries = X[rng.choice(np.nonzero(ok)[0], 16)] + 0.3 * rng.standard_normal((16, X.shape[1]))
    res = jax.vmap(matching.search, in_axes=(None, 0))(db32, jnp.asarray(queries, jnp.float32))
    d = _brute(X, ok, queries)
    got = np.asarray(res.index)
    # at the minimum to float32's round-off
    np.testing.assert_allclose(d[np.arange(16), got], d.min(1), rtol=1e-4, atol=1e-4, err_msg="float32 distance")
    # a row of the database finds itself (searchable) at distance ~0
    i = int(np.nonzero(ok)[0][7])
    one = matching.search(db, db.features[i])
    assert float(one.distance) < 1e-9 and np.allclose(np.asarray(db.features[int(one.index)]), np.asarray(db.features[i]))


def test_search_ties_go_to_the_lowest_index(db, batched_search):
    X = np.asarray(db.features).copy()
    ok = np.asarray(db.searchable)
    a, b = [int(i) for i in np.nonzero(ok)[0][[3, 120]]]  # b in a later chunk of 64 rows
    X[b] = X[a]
    tied = eqx_replace(db, X)
    q = jnp.asarray(X[[a, b]])
    res = batched_search(tied, q)
    assert np.asarray(res.index).tolist() == [a, a]
    unsearchable = int(np.nonzero(~ok)[0][0])  # a row that is not searchable is never returned
    res = batched_search(db, jnp.asarray(np.asarray(db.features)[[unsearchable]]))
    assert int(res.index[0]) != unsearchable and ok[int(res.index[0])]


def eqx_replace(db, X):
    import equinox as eqx

    X = jnp.asarray(X)
    sq = jnp.where(db.searchable, jnp.sum(X * X, axis=1), jnp.inf)
    return eqx.tree_at(lambda d: (d.features, d.squared_norms), db, (X, sq))


# --- the features -------------------------------------------------------------------------------------


def _np_quat_matrix(q):
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _np_fk(skel, q, t):
    R, P = [], []
    for j, p in enumerate(skel.parents):
        Rl = _np_quat_matrix(q[j])
        if p < 0:
            R.append(Rl)
            P.append(t[j].copy())
        else:
            R.append(R[p] @ Rl)
            P.append(P[p] + R[p] @ t[j])
    return np.array(R), np.array(P)


def test_features_match_an_independent_numpy_computation(walk, db):
    skel, motion = walk
    q = np.asarray(motion.rotations)
    t = np.asarray(motion.translations)
    dt = float(motion.frame_time)
    feet = [skel.index("LeftFoot"), skel.index("RightFoot")]
    assert db.layout.feet == tuple(feet)

    def frame(f):
        R, P = _np_fk(skel, q[f], t[f])
        qr = q[f, 0]
        yaw = 2 * np.arctan2(qr[2], qr[0])  # the twist of the root about y
        return R, P, yaw

    def to_facing(yaw, v):
        c, s = np.cos(yaw), np.sin(yaw)
        Ry = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
        return Ry.T @ v

    raw = np.asarray(db.features) / np.where(np.asarray(db.scale) == 0, 1, np.asarray(db.scale)) + np.asarray(db.mean)
    lay = db.layout
    for f in (10, 41, 70):
        Rm, Pm, _ = frame(f - 1)
        R0, P0, yaw = frame(f)
        Rp, Pp, _ = frame(f + 1)
        origin = P0[0] * np.array([1, 0, 1])
        row = raw[f]  # clip 0 comes first
        v_root = (Pp[0] - Pm[0]) / (2 * dt)
        np.testing.assert_allclose(row[lay.slice("root_velocity")], to_facing(yaw, v_root), atol=_ATOL_FEATURES,
                                   err_msg=f"root_velocity, frame {f}")
        dR = Rp[0] @ Rm[0].T
        ang = np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1))
        axis = np.array([dR[2, 1] - dR[1, 2], dR[0, 2] - dR[2, 0], dR[1, 0] - dR[0, 1]])
        w = axis / (2 * np.sin(ang)) * ang / (2 * dt) if ang > 1e-9 else axis / 2 / (2 * dt)
        np.testing.assert_allclose(row[lay.slice("root_angular_velocity")], to_facing(yaw, w), atol=1e-7,
                                   err_msg=f"root_angular_velocity, frame {f}")
        pf = np.concatenate([to_facing(yaw, P0[j] - origin) for j in feet])
        vf = np.concatenate([to_facing(yaw, (Pp[j] - Pm[j]) / (2 * dt)) for j in feet])
        np.testing.assert_allclose(row[lay.slice("foot_positions")], pf, atol=_ATOL_FEATURES,
                                   err_msg=f"foot_positions, frame {f}")
        np.testing.assert_allclose(row[lay.slice("foot_velocities")], vf, atol=_ATOL_FEATURES,
                                   err_msg=f"foot_velocities, frame {f}")
        traj_p, traj_d = [], []
        for k in (15, 30, 45):  # 0.5, 1.0, 1.5 s at 30 fps
            _, Pk, yk = frame(f + k)
            d = to_facing(yaw, Pk[0] * np.array([1, 0, 1]) - origin)
            traj_p += [d[0], d[2]]
            traj_d += [np.sin(yk - yaw), np.cos(yk - yaw)]
        np.testing.assert_allclose(row[lay.slice("trajectory_positions")], traj_p, atol=_ATOL_FEATURES,
                                   err_msg=f"trajectory_positions, frame {f}")
        np.testing.assert_allclose(row[lay.slice("trajectory_directions")], traj_d, atol=_ATOL_FEATURES,
                                   err_msg=f"trajectory_directions, frame {f}")
        heights = np.array([P0[j][1] for j in feet])
        speeds = np.linalg.norm(vf.reshape(2, 3), axis=1)
        contact = (heights - float(db.ground) < float(db.contact_height)) & (speeds < float(db.contact_speed))
        np.testing.assert_array_equal(row[lay.slice("foot_contacts")], contact.astype(float),
                                      err_msg=f"foot_contacts, frame {f}")
    # the searchable rows: every frame whose 1.5 s window ends inside its clip
    n = motion.num_frames
    assert np.asarray(db.searchable)[:n].tolist() == [f + 45 <= n - 1 for f in range(n)]
    assert np.asarray(db.searchable).sum() == 2 * (n - 45)
    # normalization: zero mean and, per block, mean deviation = weight over the searchable rows
    X = np.asarray(db.features)[np.asarray(db.searchable)]
    np.testing.assert_allclose(X.mean(0), 0.0, atol=1e-9)
    w = matching.FeatureWeights()
    for name, _ in lay.blocks:
        sd = X[:, lay.slice(name)].std(0).mean()
        if sd > 1e-9:
            np.testing.assert_allclose(sd, float(getattr(w, name)), rtol=1e-9, err_msg=name)


def test_feet_and_hands_detection_and_overrides(walk):
    skel, _ = walk
    assert [skel.names[j] for j in matching.detect_feet(skel)] == ["LeftFoot", "RightFoot"]
    assert [skel.names[j] for j in matching.detect_hands(skel)] == ["LeftHand", "RightHand"]
    assert matching.detect_feet(skel, ("LeftToeBase", "RightToeBase")) == (16, 20)
    # the hand blocks, when asked for: the hands' positions in the facing frame
    _, motion = walk
    db_h = matching.build_database([motion], skel, options=matching.FeatureOptions(use_hands=True))
    assert [b for b, _ in db_h.layout.blocks][4:6] == ["hand_positions", "hand_velocities"]
    assert db_h.num_features == 44 and db_h.layout.hands == (8, 12)
    f = 20
    _, P = _np_fk(skel, np.asarray(motion.rotations[f]), np.asarray(motion.translations[f]))
    qr = np.asarray(motion.rotations[f, 0])
    yaw = 2 * np.arctan2(qr[2], qr[0])
    c, s_ = np.cos(yaw), np.sin(yaw)
    Ry = np.array([[c, 0, s_], [0, 1, 0], [-s_, 0, c]])
    origin = P[0] * np.array([1, 0, 1])
    want = np.concatenate([Ry.T @ (P[j] - origin) for j in (8, 12)])
    raw = np.asarray(db_h.features[f]) / np.asarray(db_h.scale) + np.asarray(db_h.mean)
    np.testing.assert_allclose(raw[db_h.layout.slice("hand_positions")], want, atol=_ATOL_FEATURES, err_msg="hands")
    with pytest.raises(jaxanim.JaxanimError, match="feet: unknown joint 'LeftPaw'; valid joints"):
        matching.detect_feet(skel, ("LeftPaw", "RightFoot"))
    with pytest.raises(jaxanim.JaxanimError, match="hands: unknown joint 'Claw'"):
        matching.detect_hands(skel, ("Claw", "RightHand"))


def test_database_errors(walk, db):
    skel, motion = walk
    with pytest.raises(jaxanim.JaxanimError, match=r"clips: expected a sequence of Motion, got one Motion"):
        matching.build_database(motion, skel)
    with pytest.raises(jaxanim.JaxanimError, match=r"clips\[1\]: expected a jaxanim Motion, got str"):
        matching.build_database([motion, "walk.bvh"], skel)
    other = jaxanim.Skeleton(skel.names, skel.parents, np.asarray(skel.offsets) * 1.1, skel.channels,
                             skel.end_site_parents, skel.end_site_offsets)
    with pytest.raises(jaxanim.JaxanimError, match="b.bvh: its skeleton differs from the database's"):
        matching.build_database([motion, motion], skel, skeletons=[skel, other], sources=["a.bvh", "b.bvh"])
    with pytest.raises(jaxanim.JaxanimError, match="no frame can be searched"):
        short = jaxanim.Motion(motion.rotations[:40], motion.translations[:40], motion.frame_time)
        matching.build_database([short], skel)
    with pytest.raises(jaxanim.JaxanimError, match="clip 1: expected 21 joints"):
        matching.build_database([motion, jaxanim.Motion(motion.rotations[:, :3], motion.translations[:, :3],
                                                        motion.frame_time)], skel)
    with pytest.raises(jaxanim.JaxanimError, match="feet: unknown joint 'Paw'"):
        matching.build_database([motion], skel, options=matching.FeatureOptions(feet=("Paw", "RightFoot")))
    with pytest.raises(jaxanim.JaxanimError, match="key 2 .* follows"):
        matching.control_input([0.0, 1.0, 1.0], np.ones((3, 2)))
    with pytest.raises(jaxanim.JaxanimError, match="query: expected shape"):
        matching.search(db, jnp.zeros(5))
    with pytest.raises(jaxanim.JaxanimError, match="num_frames: expected a positive int"):
        matching.motion_matching(db, _constant(1.0, 0.0), 0)
    with pytest.raises(jaxanim.JaxanimError, match="inputs: expected a ControlInput"):
        matching.motion_matching(db, {"velocity": [[0, 1, 0]]}, 10)
    with pytest.raises(jaxanim.JaxanimError, match="start_position: expected shape"):
        matching.motion_matching(db, _constant(1.0, 0.0), 10, start_position=[0.0, 1.0, 2.0])
    with pytest.raises(jaxanim.JaxanimError, match="trajectory_times: expected increasing positive seconds"):
        matching.FeatureOptions(trajectory_times=(1.0, 0.5))
    with pytest.raises(jaxanim.JaxanimError, match="facing: key 1 is a zero vector"):
        matching.control_input([0.0, 1.0], np.ones((2, 2)), [[0.0, 1.0], [0.0, 0.0]])


# --- the controller ---------------------------------------------------------------------------------


def _max_rotation_change(q):
    q = np.asarray(q)
    return float((2 * np.arccos(np.clip(np.abs(np.sum(q[1:] * q[:-1], -1)), 0, 1))).max())


def test_walk_follows_a_constant_input(walk, db, straight):
    _, motion = walk
    res = straight
    root = np.asarray(res.motion.translations[:, 0])
    assert res.motion.num_frames == FRAMES and abs(float(res.motion.frame_time) - 1 / 30) < 1e-12
    moved = root[-1, [0, 2]] - root[0, [0, 2]]
    speed = np.linalg.norm(moved) / SECONDS
    heading = np.arctan2(moved[0], moved[1])
    # the README: speed to 0.1 % and heading to 0.1 degree (measured 0.06 % and 0.09 degree)
    assert abs(speed - 1.2) < 0.01 * 1.2, f"speed {speed:.4f} vs 1.2"
    assert abs(np.degrees(heading - 0.4)) < 1.0, f"heading {np.degrees(heading):.2f} deg vs {np.degrees(0.4):.2f}"
    # smooth: the largest per-frame joint rotation change is at most 1.5x the database's own
    own = _max_rotation_change(motion.rotations)
    out = _max_rotation_change(res.motion.rotations)
    assert out <= 1.5 * own, f"largest per-frame rotation change {out:.3f} rad vs the database's {own:.3f}"
    # it searched on schedule (every 0.15 s = 5 frames... rounded: 4 or 5) and switched sometimes
    searched = int(np.asarray(res.searched).sum())
    assert FRAMES / 6 < searched <= FRAMES / 4 + 2
    assert np.asarray(db.searchable)[np.asarray(res.rows)[np.asarray(res.switched)] - 1].all()


def test_a_turn_is_followed(db):
    """A 90° turn of the input (+z, then +x): the character ends up heading +x."""
    inp = matching.control_input([0.0, SECONDS], [[0.0, 1.2], [1.2, 0.0]])
    res = matching.motion_matching(db, inp, FRAMES)
    root = np.asarray(res.motion.translations[:, 0])
    late = root[-1, [0, 2]] - root[-46, [0, 2]]  # the last 1.5 s
    assert abs(np.degrees(np.arctan2(late[0], late[1])) - 90.0) < 15.0  # the README: 7 degrees short
    assert abs(float(res.yaw[-1]) - np.pi / 2) < np.radians(5)  # the README: facing within 2 degrees


def test_vmap_over_agents_equals_a_loop(db):
    yaws = (0.0, 1.0, -2.0)
    speeds = (1.0, 1.3, 1.1)
    inputs = [_constant(s, y) for s, y in zip(speeds, yaws)]
    loop = [matching.motion_matching(db, i, FRAMES) for i in inputs]  # the program of `straight`
    # stacked and indexed on the host (eager jnp.stack and indexing compile a small program each)
    stacked = jax.tree.map(lambda *x: np.stack([np.asarray(a) for a in x]), *inputs)
    batched = jax.vmap(lambda inp: matching.motion_matching(db, inp, FRAMES))(stacked)
    rows, rotations, translations = (np.asarray(x) for x in (batched.rows, batched.motion.rotations,
                                                             batched.motion.translations))
    for k, one in enumerate(loop):
        np.testing.assert_array_equal(rows[k], np.asarray(one.rows), err_msg=f"rows, agent {k}")
        np.testing.assert_allclose(rotations[k], np.asarray(one.motion.rotations), atol=1e-12,
                                   err_msg=f"rotations, agent {k}")
        np.testing.assert_allclose(translations[k], np.asarray(one.motion.translations), atol=1e-12,
                                   err_msg=f"translations, agent {k}")


def test_check_input_speed_reports_an_input_faster_than_the_database(walk, db):
    _, motion = walk
    step = np.linalg.norm(np.diff(np.asarray(motion.translations[:, 0])[:, [0, 2]], axis=0), axis=1)
    clip_fastest = step.max() / float(motion.frame_time)  # the root's ground speed, from the clip itself
    assert matching.check_input_speed(db, _constant(1.2, 0.4)) is None
    fast = 3.0 * clip_fastest
    message = matching.check_input_speed(db, matching.control_input([0.0, 2.0], [[0.0, 0.5], [fast, 0.0]]))
    assert message is not None and f"{fast:.3g} per s (at t = 2 s)" in message, message
    db_fastest = float(re.search(r"fastest frames move at ([0-9.e+-]+) per s", message).group(1))
    assert np.median(step) / float(motion.frame_time) < db_fastest <= clip_fastest * (1 + 5e-3)  # 3 digits


# --- the command line ---------------------------------------------------------------------------------


def _run(capsys, *argv):
    code = cli.main(["--no-compile-cache", *(str(a) for a in argv)])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_match_command(tmp_path, capsys):
    inp = tmp_path / "in.json"
    v = 1.2 * np.array([np.sin(0.4), np.cos(0.4)])
    inp.write_text(json.dumps({"velocity": [[0, *v], [SECONDS, *v]]}))
    out = tmp_path / "out.bvh"
    walk = jaxanim.default_clip_path()
    code, stdout, stderr = _run(capsys, "match", walk, "--input", inp, "--seconds", SECONDS, "--out", out, "--mirror",
                                "--clean-feet")
    assert code == 0, stderr
    assert "wrote" in stdout and "searches" in stdout and "warning" not in stderr
    # --clean-feet: the stance feet, which the trajectory adjustment slides, are planted by the IK
    planted = re.search(r"feet planted \(LeftToeBase, RightToeBase\): on the ground in (\d+) % of foot-frames, where "
                        r"their median speed went from ([0-9.e+-]+) to ([0-9.e+-]+) per s; the IK met its targets in "
                        r"(\d+)/301 frames", stdout)
    assert planted, stdout
    share, before, after, met = int(planted[1]), float(planted[2]), float(planted[3]), int(planted[4])
    assert 30 <= share <= 70 and before > 0.02 and after < 3e-4 and met == FRAMES  # the README: 3e-5 m/s after
    skel, motion = jaxanim.read_bvh(out)[:2]
    assert motion.num_frames == FRAMES and skel.num_joints == 21 and abs(float(motion.frame_time) - 1 / 30) < 1e-9
    # the written file's feet, measured again from it: where a foot is on the ground at both ends of a
    # frame step (the cleanup's own detection on the written clip) it moves less than 1 mm per s
    feet, on = jaxanim.ik.detect_foot_contacts(skel, motion)
    # the clip's FK as one program: detect_foot_contacts and the command compiled it for these 301 frames
    # (an eager vmap of FK dispatched ~45 primitives, each compiled on its own: ~1 s)
    p = np.asarray(clip_positions(skel, motion))[:, [skel.index(f) for f in feet]][..., [0, 2]]
    speed = np.linalg.norm(np.diff(p, axis=0), axis=-1) * 30.0
    assert np.median(speed[on[1:] & on[:-1]]) < 1e-3

    def bad(name, content):
        p = tmp_path / name
        p.write_text(content if isinstance(content, str) else json.dumps(content))
        return p

    other = tmp_path / "other.bvh"
    s, m = jaxanim.read_bvh(walk)[:2]
    jaxanim.write_bvh(other, jaxanim.Skeleton(s.names, s.parents, np.asarray(s.offsets) * 2, s.channels,
                                              s.end_site_parents, s.end_site_offsets), m)
    good = bad("good.json", {"velocity": [[0, 0, 1]]})
    for argv, message in (
        ([walk, "--input", bad("a.json", {"speed": []})], "a.json: unknown field(s) ['speed']; valid fields"),
        ([walk, "--input", bad("b.json", {"facing": [[0, 1, 0]]})], "b.json: missing field \"velocity\""),
        ([walk, "--input", bad("c.json", {"velocity": [[0, 1, 0], [1, 2]]})], "c.json: velocity[1]: expected [t, vx, vz]"),
        ([walk, "--input", bad("d.json", {"velocity": [[0, 1, 0], [2, 1, 0], [1, 1, 0]]})],
         "d.json: velocity[2]: times must increase, but t = 1 follows t = 2"),
        ([walk, "--input", bad("e.json", {"velocity": [[0, 1, 0]], "facing": [[0, 0, 0]]})],
         "e.json: facing[0]: a zero vector"),
        ([walk, "--input", bad("f.json", "[1, 2")], "f.json:1: not valid JSON"),
        ([walk, "--input", bad("g.json", [1, 2])], "g.json: expected a JSON object"),
        ([walk, "--input", tmp_path / "missing.json"], "missing.json: cannot read it"),
        ([walk, other, "--input", good], "other.bvh: its skeleton differs from the database's"),
        ([walk, "--input", good, "--seconds", "0"], "--seconds: expected a positive finite number"),
    ):
        argv = [*argv, "--out", out] + ([] if "--seconds" in argv else ["--seconds", 1])
        code, _, stderr = _run(capsys, "match", *argv)
        assert code == 2 and message in stderr, stderr
        assert stderr.startswith("error: ") or "\nerror: " in stderr


# --- the benchmark ------------------------------------------------------------------------------------


def test_benchmark_reduced_run():
    """``python -m benchmarks matching`` on a tiny database (one speed, 120 frames, + mirror) and 4 queries: the
    rows, their accuracy and the peers' presence; timings are not checked. The crowd table (a batched
    controller: test_vmap_over_agents_equals_a_loop runs one) is left out: its compile alone takes ~10 s.
    120 frames is the shipped walk's length: the database's batched FK, facing frames and mirror are then the
    programs the ``db`` fixture compiled (100 frames compiled them again: ~1.2 s)."""
    from benchmarks import REGISTRY, BenchConfig
    from benchmarks.matching import MatchingSizes, run_matching

    assert REGISTRY["matching"].load() is run_matching
    config = BenchConfig.make_quick(dtypes=("float64",), verbose=False)
    (search,) = run_matching(config, MatchingSizes(speeds=(1.0,), frames_per_speed=120, batches=(4,), crowd=0))
    rows = {r.implementation: r for r in search.rows}
    assert {"numpy brute force (BLAS)", "jaxanim matching.search (vmap)"} <= set(rows)
    for name in ("numpy brute force (BLAS)", "jaxanim matching.search (vmap)"):
        assert rows[name].measured and rows[name].success == 1.0, name
    faiss = rows["faiss IndexFlatL2 (exact)"]  # measured where faiss imports, else a row saying why not
    assert faiss.is_peer and (faiss.measured and faiss.dtype == "float32" and faiss.success == 1.0
                              or faiss.skipped is not None and "faiss" in faiss.skipped), faiss
    # without a float32 row the speed target falls back to the chunked NumPy brute force, in float64
    (speed, _) = search.targets
    assert "chunked NumPy" in speed.text and "float64" in speed.text, speed.text


def test_benchmark_chunked_numpy_search_is_one_argmin():
    """The benchmark's chunked NumPy peer equals one argmin over the whole distance array, for chunks and query
    blocks that do not divide the sizes, with a tie across chunks (the first row wins) and masked rows."""
    from benchmarks.matching import _numpy_search

    rng = np.random.default_rng(1)
    X = rng.standard_normal((1000, 8))
    X[700] = X[3]
    ok = rng.random(1000) > 0.1
    ok[[3, 700]] = True
    sq = np.where(ok, (X * X).sum(1), np.inf)
    Q = rng.standard_normal((50, 8))
    Q[0] = X[3]
    full = sq[None] - 2 * Q @ X.T
    want = full.argmin(1)
    for queries, rows in ((7, 64), (50, 999), (1024, 8192)):
        idx, dist = _numpy_search(X, sq, Q, queries, rows)
        np.testing.assert_array_equal(idx, want)
        np.testing.assert_allclose(dist, full[np.arange(len(Q)), want] + (Q * Q).sum(1), rtol=1e-12, atol=1e-12)
    assert idx[0] == 3 and ok[idx].all()
