"""The robot and the map that ship inside the package, so that retargeting runs on shipped data alone.

``humanoid.xml`` is jaxanim's own small humanoid: the joint layout and the body and joint names of
a 29-joint humanoid robot in the style of the Unitree G1 (6 joints per leg, 3 at the waist, 7 per
arm, a free base on the pelvis), with its own simple dimensions (about 1.3 m tall, the soles on the
ground at ``qpos0``) and primitive geoms; a map written for it also serves a G1.
``walk_humanoid.json`` maps the shipped walk (:func:`jaxanim.default_clip_path`) onto it.
"""

from __future__ import annotations

import pathlib

_DATA = pathlib.Path(__file__).resolve().parents[1] / "data"


def default_robot_path() -> pathlib.Path:
    """The shipped humanoid's MJCF file (``jaxanim/data/humanoid.xml``)."""
    return _DATA / "humanoid.xml"


def default_mapping_path() -> pathlib.Path:
    """The map of the shipped walk onto the shipped humanoid (``jaxanim/data/walk_humanoid.json``);
    :func:`jaxanim.retargeting.default_mapping_path` is its public home."""
    return _DATA / "walk_humanoid.json"
