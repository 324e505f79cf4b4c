"""A retargeting map found from the shapes of the clip's skeleton and of the robot (issue 58).

:func:`auto_map_dict` reads both trees, the skeleton in its rest pose (every joint at its parent
plus its OFFSET, as :func:`jaxanim.kinematics.forward_kinematics` puts it with identity rotations)
and the robot in its zero pose (``qpos0``), and writes the map that a person would write by hand
(:mod:`._mapping`'s JSON contract, the pairs and weights of the shipped map); :func:`auto_map` parses
it. Only the topology and the geometry are read; names are never needed (a renamed skeleton or robot
gets the same map). Each tree is read the same way, unless said:

* **root**: the skeleton's joint 0; the robot's body moved by its free joint, else its top body
  (the largest subtree under the world where there are several).
* **up** and **legs**: below the root the tree is followed down to the first body where two
  branches reach the lower half of the stance (from the root's height down to the lowest point,
  collision points and End Sites included); those two are the legs. Up is the axis (the skeleton's
  Y or Z, the robot's Z or Y) along which the shallower of the two legs reaches deepest.
* each leg's **line** runs from its first body to its lowest one. The **ankle** ends the line's
  last mostly vertical segment (the toe that follows runs forward); the **knee** is the body
  between the hip (the line's first body) and the ankle farthest from both (the larger of the two
  distances' minimum). The source's foot is its ankle joint; the robot's is the line's deepest body
  down to the ankle with collision points on it or below it (the sole that the solve keeps on the
  ground), else the ankle (a URDF whose meshes are missing: its sole frame).
* **facing**: the feet point forward: the horizontal offset from each ankle's last moving body to
  the middle of everything below it (toes, End Sites, foot geometry, sole frames). Left is
  ``up x forward`` (BVH: Y up, facing +Z, +X on the left; the G1 faces +X, dm_control's CMU
  humanoid -Y), and each leg's side is where its ankle lies.
* **arms** and **chest**: of the bodies outside the legs, the chest is the one with two branches
  that go sideways, one to the left and one to the right (each branch's bodies, on average, a
  quarter of its reach or more to that side), the pair that reaches farthest (so a pair of eyes
  loses to the arms). Each arm's line follows its single moving child. The source's **wrist** is
  the first joint where the line branches (fingers) or ends; a robot's is the last moving body
  before its line branches (the fingers' or the thumb's body: dm_control's ``lwrist``, not
  ``lhand``) or at its end (the G1's last wrist link). The **shoulder** is the line's first body
  that lies sideways from the chest by a tenth of the wrist's distance (a clavicle that starts at
  the spine is passed over) and the **elbow** the body between shoulder and wrist farthest from
  both, as the knee.

Where bodies share a position (a joint's several hinges, each on a body of its own), the deepest is
taken: it moves with all of them. A tree that cannot be read so (fewer than two legs, no arms, feet
that do not show which way is forward, both legs on one side) raises a :class:`JaxanimError` naming
what is missing. :func:`calibrate` computes the rest from the map (axes, scale, offsets); a robot
that lies in its zero pose (dm_control's V2020 CMU walker stands along +Y until it is attached to an
arena) is stood up first by its free joint (:func:`upright`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .. import _tree
from .._errors import JaxanimError
from ..robots._kinematics import forward_kinematics
from ..robots._robot import Robot
from ..skeleton._skeleton import Skeleton
from ._mapping import RetargetMap, load_mapping

__all__ = ["auto_map", "auto_map_dict"]

_AXES = {"y": np.array([0.0, 1.0, 0.0]), "z": np.array([0.0, 0.0, 1.0])}
#: The ups tried, in order of preference (the map's ``source_up`` is "y" or "z").
_SOURCE_UPS = ("y", "z")
_ROBOT_UPS = ("z", "y")
#: A branch is sideways when its bodies lie, on average, this fraction of its reach to one side.
_SIDEWAYS = 0.25
#: The shoulder: the first arm body this fraction of the chest-to-wrist distance to the side.
_SHOULDER = 0.1
#: Positions closer than this fraction of the stance height are the same (several hinges' bodies).
_SAME = 1e-9

#: The pairs in the order of the hand-written maps, with their weights.
_FOOT = {"foot": True, "position_weight": 1.0, "orientation_weight": 0.5}
_KNEE = {"foot": False, "position_weight": 1.0, "orientation_weight": 0.0}
_CHEST = {"foot": False, "position_weight": 1.0, "orientation_weight": 0.5}
#: An elbow's orientation weight is small: the robot's elbow link lacks the forearm's pronation, which the source's
#: forearm joint carries (the wrist's roll has it), so its orientation pulls the upper arm round.
_ELBOW = {"foot": False, "position_weight": 0.5, "orientation_weight": 0.01}
_WRIST = {"foot": False, "position_weight": 0.5, "orientation_weight": 0.1}


class _Shape(NamedTuple):
    """A tree in its rest / zero pose, on the host in float64."""

    what: str  # "skeleton" or "robot", for the messages
    names: tuple[str, ...]
    parents: tuple[int, ...]  # -1 at a top
    root: int
    pos: np.ndarray  # [N, 3]
    moving: np.ndarray  # [N] bool: a joint moves the body (every skeleton joint)
    extra: np.ndarray  # [K, 3] End Sites / collision points
    extra_node: np.ndarray  # [K] the node each hangs from
    below: np.ndarray  # [N, N] bool: below[a, j]: j is a or below it
    children: tuple[tuple[int, ...], ...]


class _Body(NamedTuple):
    """What was read from one tree: node indices."""

    up: str
    foot: tuple[int, int]  # left, right
    knee: tuple[int, int]
    chest: int
    elbow: tuple[int, int]
    wrist: tuple[int, int]


def _shape(what, names, parents, root, pos, moving, extra, extra_node) -> _Shape:
    children = [[] for _ in parents]
    for j, p in enumerate(parents):
        if p >= 0:
            children[p].append(j)
    return _Shape(what, tuple(names), tuple(parents), root, pos, np.asarray(moving, bool), extra.reshape(-1, 3),
                  np.asarray(extra_node, np.int64), np.asarray(_tree.subtree(parents)), tuple(map(tuple, children)))


def _skeleton_shape(skeleton: Skeleton) -> _Shape:
    offsets = np.asarray(skeleton.offsets, np.float64)
    pos = np.zeros_like(offsets)
    for j, p in enumerate(skeleton.parents):  # topologically sorted: a parent comes first
        pos[j] = offsets[j] + (pos[p] if p >= 0 else 0.0)
    ends = list(skeleton.end_site_parents)
    extra = pos[ends] + np.asarray(skeleton.end_site_offsets, np.float64).reshape(-1, 3)
    return _shape("skeleton", skeleton.names, skeleton.parents, 0, pos, np.ones(len(pos), bool), extra, ends)


def _robot_root(robot: Robot) -> int:
    size = np.asarray(_tree.subtree(robot.body_parents)).sum(axis=1)
    free = [b for b, t in zip(robot.jnt_bodies, robot.jnt_types) if t == "free"]
    tops = free or [b for b in range(1, robot.num_bodies) if robot.body_parents[b] == 0]
    if not tops:
        raise JaxanimError("auto_map: the robot has no body under the world")
    return max(tops, key=lambda b: (size[b], -b))


def _robot_shape(robot: Robot) -> _Shape:
    zero = forward_kinematics(robot, robot.qpos0)
    xpos, xmat = np.asarray(zero.xpos, np.float64), np.asarray(zero.xmat, np.float64)
    pb = np.asarray(robot.point_bodies, np.int64)
    extra = xpos[pb] + np.einsum("kij,kj->ki", xmat[pb], np.asarray(robot.point_pos, np.float64).reshape(-1, 3))
    moving = np.zeros(robot.num_bodies, bool)
    moving[list(robot.jnt_bodies)] = True
    return _shape("robot", robot.body_names, robot.body_parents, _robot_root(robot), xpos, moving, extra, pb)


def _lowest(s: _Shape, h: np.ndarray, he: np.ndarray) -> np.ndarray:
    """``[N]`` the lowest height on or below each node (bodies, End Sites and collision points)."""
    low = np.where(s.below, h[None, :], np.inf).min(axis=1)
    if len(he):
        low = np.minimum(low, np.where(s.below[:, s.extra_node], he[None, :], np.inf).min(axis=1))
    return low


class _Legs(NamedTuple):
    hips: int  # the body the legs branch from
    legs: tuple[int, int]
    depth: float  # how far the shallower leg reaches below the root
    stance: float  # the root's height above the lowest point


def _find_legs(s: _Shape, up: np.ndarray) -> _Legs | str:
    """The two legs under ``up``, or why there are none."""
    h, he = s.pos @ up, s.extra @ up
    low = _lowest(s, h, he)
    stance = h[s.root] - low[s.root]
    if not stance > 0:
        return f"nothing lies below the root {s.names[s.root]!r}"
    half = h[s.root] - 0.5 * stance
    x, one = s.root, None
    while True:
        kids = sorted((k for k in s.children[x] if low[k] < half), key=lambda k: low[k])
        if len(kids) >= 2:
            return _Legs(x, (kids[0], kids[1]), float(h[s.root] - max(low[kids[0]], low[kids[1]])), float(stance))
        if not kids:
            where = f"only the branch through {s.names[one]!r}" if one is not None else "no branch"
            return f"{where} reaches down to the ground from the root {s.names[s.root]!r}"
        one = kids[0] if one is None else one
        x = kids[0]


def _path(s: _Shape, top: int, node: int) -> list[int]:
    path = [node]
    while path[-1] != top:
        path.append(s.parents[path[-1]])
    return path[::-1]


def _between(s: _Shape, line: list[int], a: int, b: int, tol: float) -> int | None:
    """The node of ``line`` strictly between indices ``a`` and ``b`` farthest from both ends (the
    largest smaller distance; the deepest of equals)."""
    best, best_score = None, -np.inf
    for i in range(a + 1, b):
        p = s.pos[line[i]]
        score = min(np.linalg.norm(p - s.pos[line[a]]), np.linalg.norm(s.pos[line[b]] - p))
        if score >= best_score - tol:
            best, best_score = line[i], max(score, best_score)
    return best


class _Leg(NamedTuple):
    line: list[int]
    ankle: int  # index into line
    knee: int
    foot: int  # the pair's node


def _leg(s: _Shape, top: int, up: np.ndarray, tol: float) -> _Leg:
    below = np.flatnonzero(s.below[top])
    h = s.pos @ up
    line = _path(s, top, int(below[np.argmin(h[below])]))
    vertical = []
    for i in range(1, len(line)):
        d = s.pos[line[i]] - s.pos[line[i - 1]]
        v = abs(d @ up)
        if v > tol and v >= np.linalg.norm(d - (d @ up) * up):
            vertical.append(i)
    ankle = vertical[-1] if vertical else len(line) - 1
    knee = _between(s, line, 0, ankle, tol)
    if knee is None:
        raise JaxanimError(f"auto_map: the {s.what}'s leg through {s.names[top]!r} has no knee: no {_kind(s)} between "
                           f"the hip {s.names[line[0]]!r} and the ankle {s.names[line[ankle]]!r}")
    foot = line[ankle]
    if s.what == "robot":  # the deepest body down to the ankle that has collision geometry on it or below it
        with_points = set(s.extra_node.tolist())
        for node in reversed(line[:ankle + 1]):
            if any(s.below[node, b] for b in with_points):
                foot = node
                break
    return _Leg(line, ankle, knee, foot)


def _kind(s: _Shape) -> str:
    return "joint" if s.what == "skeleton" else "body"


def _forward(s: _Shape, leg: _Leg, up: np.ndarray) -> np.ndarray:
    """The horizontal offset from the ankle's last moving body to the middle of what lies below it."""
    ankle = next((n for n in reversed(leg.line[:leg.ankle + 1]) if s.moving[n]), leg.line[leg.ankle])
    points = np.concatenate([s.pos[s.below[ankle]], s.extra[s.below[ankle, s.extra_node]]])
    d = points.mean(axis=0) - s.pos[ankle]
    return d - (d @ up) * up


def _arm_line(s: _Shape, top: int, below_moves: np.ndarray) -> tuple[list[int], int]:
    """The line from ``top`` along single moving children, and how many moving children its last has."""
    line = [top]
    while True:
        kids = [k for k in s.children[line[-1]] if below_moves[k]]
        if len(kids) != 1:
            return line, len(kids)
        line.append(kids[0])


def _arm(s: _Shape, chest: int, top: int, left: np.ndarray, tol: float) -> tuple[int, int]:
    """``(elbow, wrist)`` of the arm that starts at ``top``."""
    below_moves = (s.below & s.moving[None, :]).any(axis=1)
    line, branches = _arm_line(s, top, below_moves)
    if s.what == "skeleton":
        w = len(line) - 1
    else:
        ends = line[:-1] if branches >= 2 else line
        w = next((i for i in range(len(ends) - 1, -1, -1) if s.moving[ends[i]]), None)
        if w is None:
            raise JaxanimError(f"auto_map: the robot's arm through {s.names[top]!r} has no moving body before its hand")
    reach = np.linalg.norm(s.pos[line[w]] - s.pos[chest])
    side = np.abs((s.pos[line[:w + 1]] - s.pos[chest]) @ left)
    shoulder = int(np.flatnonzero(side >= _SHOULDER * reach)[0]) if np.any(side >= _SHOULDER * reach) else 0
    elbow = _between(s, line, shoulder, w, tol)
    if elbow is None:
        raise JaxanimError(f"auto_map: the {s.what}'s arm through {s.names[top]!r} has no elbow: no {_kind(s)} between "
                           f"the shoulder {s.names[line[shoulder]]!r} and the wrist {s.names[line[w]]!r}")
    return elbow, line[w]


def _read(s: _Shape, ups: tuple[str, ...]) -> _Body:
    found = {u: _find_legs(s, _AXES[u]) for u in ups}
    valid = {u: f for u, f in found.items() if isinstance(f, _Legs)}
    if not valid:
        raise JaxanimError(f"auto_map: the {s.what} has fewer than two legs: {found[ups[0]]} (with {ups[0].upper()} "
                           f"up; nor with {' or '.join(u.upper() for u in ups[1:])} up)")
    up_name = max(valid, key=lambda u: valid[u].depth)  # the first of equals
    up, legs = _AXES[up_name], valid[up_name]
    tol = _SAME * legs.stance
    two = [_leg(s, top, up, tol) for top in legs.legs]
    forward = sum(_forward(s, leg, up) for leg in two)
    if not np.linalg.norm(forward) > 1e-3 * legs.stance:
        raise JaxanimError(f"auto_map: the {s.what}'s feet do not show which way it faces: nothing (toes, End Sites, "
                           f"foot geometry) lies ahead of or behind its ankles {s.names[two[0].line[two[0].ankle]]!r} "
                           f"and {s.names[two[1].line[two[1].ankle]]!r}")
    left = np.cross(up, forward / np.linalg.norm(forward))
    sides = [(s.pos[leg.line[leg.ankle]] - s.pos[legs.hips]) @ left for leg in two]
    if not sides[0] * sides[1] < 0:
        raise JaxanimError(f"auto_map: the {s.what}'s legs through {s.names[legs.legs[0]]!r} and "
                           f"{s.names[legs.legs[1]]!r} do not lie one on each side")
    if sides[0] < 0:
        two = two[::-1]
    # the arms: two branches of one body outside the legs, one to each side, the pair that reaches farthest
    upper = s.below[s.root] & ~s.below[legs.legs[0]] & ~s.below[legs.legs[1]]
    best, best_reach = None, 0.0
    for c in np.flatnonzero(upper):
        sideways = []
        for k in s.children[c]:
            if not upper[k]:
                continue
            points = np.concatenate([s.pos[s.below[k]], s.extra[s.below[k, s.extra_node]]]) - s.pos[c]
            reach = np.linalg.norm(points, axis=1).max()
            side = np.mean((s.pos[s.below[k]] - s.pos[c]) @ left)
            if reach > tol and abs(side) >= _SIDEWAYS * reach:
                sideways.append((k, side, reach))
        for kl, side_l, reach_l in sideways:
            for kr, side_r, reach_r in sideways:
                if side_l > 0 > side_r and min(reach_l, reach_r) > best_reach:
                    best, best_reach = (int(c), kl, kr), min(reach_l, reach_r)
    if best is None:
        raise JaxanimError(f"auto_map: the {s.what} has no arms: no {_kind(s)} outside the legs has two branches that "
                           f"go sideways, one to the left and one to the right")
    chest, top_l, top_r = best
    arms = [_arm(s, chest, top, left, tol) for top in (top_l, top_r)]
    return _Body(up_name, (two[0].foot, two[1].foot), (two[0].knee, two[1].knee), chest,
                 (arms[0][0], arms[1][0]), (arms[0][1], arms[1][1]))


def _target(robot: Robot, body: int) -> str:
    name = robot.body_names[body]
    return f"body:{name}" if name in robot.site_names else name


def auto_map_dict(skeleton: Skeleton, robot: Robot) -> dict:
    """The retargeting map of ``skeleton`` onto ``robot`` found from their shapes, as a JSON-ready dict.

    The root, the feet (planted), the knees, the chest (where the arms branch), the elbows and the
    wrists, with the weights of the shipped map, ``source_up`` detected and ``scale: "auto"``; no
    offsets (:func:`calibrate` computes them). See the module docstring for how each is found.

    Args:
        skeleton: the source, read in its rest pose (identity rotations, OFFSETs).
        robot: the robot, read in its zero pose (``qpos0``).

    Returns:
        ``{"root": {...}, "source_up": "y" | "z", "scale": "auto", "pairs": [{"source", "target",
        "foot", "position_weight", "orientation_weight"}, ...]}``: left foot, right foot, left knee,
        right knee, chest, left elbow, right elbow, left wrist, right wrist. A robot body whose name
        is also a site's is written ``"body:NAME"``.

    Raises:
        JaxanimError: when either tree cannot be read as a humanoid (fewer than two legs, no arms, no
            knee or elbow, feet that do not show which way is forward), naming what is missing.
    """
    if not isinstance(skeleton, Skeleton):
        raise JaxanimError(f"skeleton: expected a Skeleton, got {type(skeleton).__name__}")
    if not isinstance(robot, Robot):
        raise JaxanimError(f"robot: expected a Robot (robots.load_robot), got {type(robot).__name__}")
    src = _read(_skeleton_shape(skeleton), _SOURCE_UPS)
    rob_shape = _robot_shape(robot)
    rob = _read(rob_shape, _ROBOT_UPS)
    pairs = []
    for field, weights in (("foot", _FOOT), ("knee", _KNEE), ("chest", _CHEST), ("elbow", _ELBOW), ("wrist", _WRIST)):
        a, b = getattr(src, field), getattr(rob, field)
        for j, body in (zip(a, b) if isinstance(a, tuple) else ((a, b),)):
            pairs.append({"source": skeleton.names[j], "target": _target(robot, body), **weights})
    return {"root": {"source": skeleton.names[0], "target": _target(robot, rob_shape.root)},
            "source_up": src.up, "scale": "auto", "pairs": pairs}


def auto_map(skeleton: Skeleton, robot: Robot) -> RetargetMap:
    """:func:`auto_map_dict`, parsed (:func:`load_mapping`): the map to hand to :func:`calibrate`,
    :func:`prepare_retarget` or :func:`retarget`.

    Raises:
        JaxanimError: as :func:`auto_map_dict`.
    """
    return load_mapping(auto_map_dict(skeleton, robot))
