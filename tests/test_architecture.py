"""The package layout: imports run one way, and every import path of the 0.1 README still works."""

from __future__ import annotations

import ast
import importlib
import pathlib

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]


def _units(package: str) -> dict[pathlib.Path, str]:
    """Each source file -> its unit: a subpackage (all its files), a top-level module, or the face."""
    root = REPO / package
    out = {}
    for path in root.rglob("*.py"):
        rel = path.relative_to(root)
        if len(rel.parts) > 1:
            out[path] = f"{package}.{rel.parts[0]}"
        elif rel.stem == "__init__":
            out[path] = package
        else:
            out[path] = f"{package}.{rel.stem}"
    return out


def _imported_modules(path: pathlib.Path, package: str) -> set[str]:
    """Absolute names of what ``path`` imports, at any depth (function bodies too): ``import a.b``
    gives ``a.b``; ``from a import b`` gives ``a.b`` (a submodule, or a name of ``a``)."""
    module_parts = [package, *path.relative_to(REPO / package).with_suffix("").parts]
    if module_parts[-1] == "__init__":
        module_parts = module_parts[:-1]
    is_package = path.name == "__init__.py"
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module_parts if is_package else module_parts[:-1]
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module
            names.update(f"{mod}.{a.name}" for a in node.names)
    return names


def _graph() -> dict[str, set[str]]:
    units = {}
    for package in ("jaxanim", "solvers"):
        units.update(_units(package))
    known = set(units.values())
    graph = {u: set() for u in known}
    for path, unit in units.items():
        package = unit.split(".")[0]
        for name in _imported_modules(path, package):
            parts = name.split(".")
            # the longest prefix that is a unit: `jaxanim.physics._model.X` -> `jaxanim.physics`,
            # `jaxanim.rotations` -> itself, `jaxanim.__version__` -> the face `jaxanim`
            target = next((".".join(parts[:k]) for k in (2, 1) if ".".join(parts[:k]) in known), None)
            if target is not None and target != unit:
                graph[unit].add(target)
    return graph


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}  # 1 on the stack, 2 done
    stack: list[str] = []

    def visit(u):
        state[u] = 1
        stack.append(u)
        for v in sorted(graph[u]):
            if state.get(v) == 1:
                return stack[stack.index(v):] + [v]
            if v not in state and (found := visit(v)):
                return found
        stack.pop()
        state[u] = 2
        return None

    for u in sorted(graph):
        if u not in state and (found := visit(u)):
            return found
    return None


def test_no_import_cycle_between_units():
    graph = _graph()
    assert {"jaxanim.kinematics", "jaxanim.physics", "solvers.lqr"} <= set(graph)  # the parse sees them
    assert "jaxanim.rotations" in graph["jaxanim.physics"]
    cycle = _cycle(graph)
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def _file_graph() -> dict[str, set[str]]:
    """Module -> the modules of this repository it imports (a package's ``__init__`` is the package's
    name), at any depth: an import inside a function body counts."""
    modules = {}
    for package in ("jaxanim", "solvers"):
        for path in (REPO / package).rglob("*.py"):
            parts = [package, *path.relative_to(REPO / package).with_suffix("").parts]
            modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    graph = {}
    for name, path in modules.items():
        targets = set()
        for imported in _imported_modules(path, name.split(".")[0]):
            parts = imported.split(".")
            target = next((".".join(parts[:k]) for k in range(len(parts), 0, -1) if ".".join(parts[:k]) in modules),
                          None)
            if target is not None and target != name:
                targets.add(target)
        graph[name] = targets
    return graph


def test_no_import_cycle_between_files():
    """Within a unit too: two private modules never import each other, not even from a function body."""
    graph = _file_graph()
    assert "jaxanim.skinning._mesh" in graph["jaxanim.skinning._skin"]  # the parse sees them
    cycle = _cycle(graph)
    assert cycle is None, "import cycle between files: " + " -> ".join(cycle)


def test_the_cycle_check_finds_a_cycle():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None


def _private_names_from_other_units(package: str) -> list[str]:
    """``file: name from module`` for each underscore name a file of one subpackage imports from a module of
    another (its own modules and the package's top-level helpers are its to use)."""
    out = []
    for path, unit in _units(package).items():
        module_parts = [package, *path.relative_to(REPO / package).with_suffix("").parts]
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if not isinstance(node, ast.ImportFrom):
                continue
            if node.level:
                base = module_parts[: len(module_parts) - node.level]
                source = ".".join(base + ([node.module] if node.module else []))
            else:
                source = node.module or ""
            parts = source.split(".")
            other = (parts[0] == package and len(parts) >= 3 and (REPO / package / parts[1]).is_dir()
                     and f"{package}.{parts[1]}" != unit)
            if other:
                out += [f"{path.relative_to(REPO)}: {a.name} from {source}" for a in node.names
                        if a.name.startswith("_")]
    return out


def test_no_unit_imports_another_units_private_names():
    """What one subpackage shares with another is a name without an underscore (its internal interface),
    never a private one."""
    assert _private_names_from_other_units("jaxanim") == []


def test_solvers_never_imports_jaxanim():
    assert not any(v.startswith("jaxanim") for u, vs in _graph().items() if u.startswith("solvers") for v in vs)


def test_layers_run_one_way():
    graph = _graph()
    # a unit may import only these jaxanim units (and solvers); _linalg, the products at a stated
    # precision, sits at the bottom beside _errors and _types
    base = {"jaxanim._errors", "jaxanim._types", "jaxanim._linalg"}
    below = {
        "jaxanim.rotations": {"jaxanim._errors", "jaxanim._types"},
        "jaxanim.skeleton": base | {"jaxanim._tree", "jaxanim.rotations"},
        "jaxanim.physics": base | {"jaxanim._tree", "jaxanim.rotations"},
        "jaxanim.matching": base | {"jaxanim._tree", "jaxanim.rotations", "jaxanim.skeleton", "jaxanim.kinematics"},
        "jaxanim.skinning": base | {"jaxanim.rotations", "jaxanim.skeleton", "jaxanim.kinematics"},
        "jaxanim.splines": base | {"jaxanim.rotations", "jaxanim.skeleton"},
        "jaxanim.robots": base | {"jaxanim._tree", "jaxanim.rotations", "jaxanim.skeleton", "jaxanim.kinematics"},
        "jaxanim.retargeting": base | {"jaxanim._tree", "jaxanim.rotations", "jaxanim.skeleton", "jaxanim.kinematics",
                                       "jaxanim.robots", "jaxanim.ik"},
    }
    for unit, allowed in below.items():
        extra = {v for v in graph[unit] if v.startswith("jaxanim")} - allowed
        assert not extra, f"{unit} imports {sorted(extra)}"


def test_at_most_eight_top_level_modules():
    modules = sorted(p.name for p in (REPO / "jaxanim").glob("*.py"))
    assert len(modules) <= 8, modules


# Every import path that the 0.1 README documents, module -> names.
README_01 = {
    "jaxanim": "read_bvh write_bvh forward_kinematics jacobian apply_increment global_to_local center_of_mass "
    "resample resample_at retarget rest_alignment shard_batch JaxanimError BVHParseError Skeleton Motion FKResult "
    "rotations ik physics character rigid joints contact control balance",
    "jaxanim.rotations": "quat_multiply quat_conjugate quat_inverse quat_apply quat_normalize quat_canonical "
    "quat_to_matrix matrix_to_quat rotvec_to_quat quat_to_rotvec rotvec_to_matrix matrix_to_rotvec "
    "axis_angle_to_quat quat_to_axis_angle euler_to_matrix matrix_to_euler euler_to_quat quat_to_euler slerp "
    "nlerp rotation_between matrix_to_sixd sixd_to_matrix skew rotation_angle quat_distance",
    "jaxanim.ik": "Target EulerLimit SwingTwistLimit solve_ik limit_violation solve_ik_clip solve_ik_ccd "
    "IKSolution targets_from_json",
    "jaxanim.rigid": "make_bodies make_state step_free",
    "jaxanim.joints": "make_joints",
    "jaxanim.physics": "make_model step rollout SimResult to_mjcf",
    "jaxanim.contact": "make_ground",
    "jaxanim.control": "pd_joint_torques",
    "jaxanim.character": "build_character tracking_controller character_pose export_mjcf",
    "jaxanim.balance": "balance_controller standing_pose",
    "solvers": "least_squares GaussNewton LevenbergMarquardt GradientDescent OptimistixSolver JaxoptSolver "
    "Solution RESULTS lqr dare care ilqr ddp mpc mpc_step shard_batch problems",
    "solvers.problems": "acrobot pendulum cart_pole unicycle double_integrator pd_servo_tracking",
}


@pytest.mark.parametrize("module", sorted(README_01))
def test_01_import_paths_still_work(module):
    mod = importlib.import_module(module)
    missing = [name for name in README_01[module].split() if not hasattr(mod, name)]
    assert not missing, f"{module} lacks {missing}"


def test_01_modules_are_the_same_objects_either_way():
    import jaxanim
    from jaxanim import balance, rigid  # noqa: F401  (the `from ... import` form)
    from jaxanim.rigid import make_bodies

    assert jaxanim.rigid.make_bodies is make_bodies is jaxanim.physics.make_bodies
    assert jaxanim.balance.balance_controller is jaxanim.character.balance_controller
    assert importlib.import_module("jaxanim.fk").forward_kinematics is jaxanim.forward_kinematics


def test_importing_the_packages_starts_no_jax_backend():
    """Importing jaxanim computes nothing: a default argument or field that builds arrays at import time
    would start XLA's backend, after which the user's ``XLA_FLAGS`` and ``jax.config`` platform
    settings no longer apply (a ``FeatureOptions()`` default did)."""
    import subprocess
    import sys

    code = ("import jaxanim, jaxanim.app, solvers; from jaxanim.app import _cli; "
            "from jax._src import xla_bridge as xb; print(sorted(xb._backends))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]", out.stdout


def test_no_library_file_over_700_lines():
    """The layout keeps each module of jaxanim, solvers and benchmarks within 700 lines."""
    files = [p for package in ("jaxanim", "solvers", "benchmarks") for p in (REPO / package).rglob("*.py")]
    long = {str(p.relative_to(REPO)): n for p in files if (n := len(p.read_text(encoding="utf-8").splitlines())) > 700}
    assert not long, f"files over 700 lines: {long}"


def test_moved_robot_names_warn_and_name_their_new_home():
    """Retargeting and the robots' IK moved out of ``jaxanim.robots`` (issue 58); the old names still work for
    one release, each with a DeprecationWarning that names the new home, and are the same objects."""
    import warnings

    from jaxanim import ik, retargeting, robots

    for name, home in (("retarget", retargeting), ("RetargetOptions", retargeting), ("summary", retargeting),
                       ("load_mapping", retargeting), ("default_mapping_path", retargeting),
                       ("solve_ik_robot", ik), ("RobotIKSolution", ik)):
        with pytest.warns(DeprecationWarning, match=rf"jaxanim\.robots\.{name} has moved to {home.__name__}\.{name}"):
            assert getattr(robots, name) is getattr(home, name)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert robots.load_robot and robots.Robot  # the robot's own names do not warn
    with pytest.raises(AttributeError, match="no attribute 'nonsense'"):
        robots.nonsense  # noqa: B018
