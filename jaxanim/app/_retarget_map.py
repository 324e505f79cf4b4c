"""``jaxanim retarget-map SOURCE.bvh --robot ROBOT.xml|ROBOT.urdf --out MAP.json`` (issue 58): the
retargeting map found from the clip's skeleton and the robot (:func:`jaxanim.retargeting.auto_map_dict`),
written for a person to read and edit."""

from __future__ import annotations

import argparse
import json
import pathlib

from .._errors import JaxanimError
from ._common import _UI, _warnings_to


def _format_map(mapping: dict) -> str:
    """A map as JSON laid out like the shipped one: a line per key, a line per pair."""
    lines = [f"  {json.dumps(k)}: {json.dumps(v)}," for k, v in mapping.items() if k != "pairs"]
    pairs = ",\n".join(f"    {json.dumps(p)}" for p in mapping["pairs"])
    return "{\n" + "\n".join(lines) + f'\n  "pairs": [\n{pairs}\n  ]\n}}\n'


def _cmd_retarget_map(args: argparse.Namespace, ui: _UI) -> int:
    from .. import retargeting, robots  # noqa: PLC0415 (mujoco is an optional extra)
    from ..skeleton import default_clip_path, read_clip  # noqa: PLC0415

    out = pathlib.Path(args.out)
    if out.suffix != ".json":
        raise JaxanimError(f"--out {args.out}: expected a .json file")
    robot_path = args.robot or robots.default_robot_path()
    source = args.source or default_clip_path()
    skeleton, _ = read_clip(source, body_model=args.body_model)
    with _warnings_to(ui):  # a URDF's missing meshes, one line each
        robot = robots.load_robot(robot_path)
        mapping = retargeting.auto_map_dict(skeleton, robot)
    out.write_text(_format_map(mapping), encoding="utf-8")
    ui.result(f"wrote {out}: {skeleton.num_joints} joints of {pathlib.Path(source).name} onto {robot.name} "
              f"(root {mapping['root']['source']} -> {mapping['root']['target']}, source up {mapping['source_up']})")
    for p in mapping["pairs"]:
        ui.result(f"  {p['source']} -> {p['target']}{' (foot)' if p['foot'] else ''}")
    return 0


def add_retarget_map_parser(sub, common) -> None:
    p = sub.add_parser("retarget-map", parents=[common], help="find the retargeting map of a clip onto a robot "
                       "(JSON to read and edit)",
                       description="Find the retargeting map of a BVH clip onto a robot from their shapes alone "
                                   "(jaxanim.retargeting.auto_map_dict, needs jaxanim[robots]): the root, the feet "
                                   "(planted), the knees, the chest, the elbows and the wrists, left and right told "
                                   "by which way the feet point, names not needed. Writes it as indented JSON, "
                                   "the map that `jaxanim retarget --map` reads (`--map auto` finds it on the fly). "
                                   "Defaults: the shipped walk and humanoid.")
    p.add_argument("source", nargs="?", metavar="SOURCE.bvh", help="the clip (default: the shipped walk)")
    p.add_argument("--robot", metavar="ROBOT.xml|ROBOT.urdf", help="the robot (default: the shipped humanoid)")
    p.add_argument("--out", "-o", default="retarget_map.json", metavar="MAP.json",
                   help="output (default retarget_map.json)")
    p.set_defaults(func=_cmd_retarget_map)
