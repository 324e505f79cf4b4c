"""``jaxanim demo``: the pipeline on the shipped clip, a list of steps (:data:`DEMO_STEPS`) with timings;
later features append theirs to it."""

from __future__ import annotations

import argparse
import dataclasses
import pathlib
import time
from collections.abc import Callable

import jax
import numpy as np

from ._common import _UI, _Clip, _clip_fk, _FKRun, _fk_arrays, _load, _ms, _num, _plot, _save_npz

_DEMO_TIMING_REPEATS = 20


@dataclasses.dataclass
class DemoState:
    """What the demo steps share: the options, the clip and what earlier steps computed."""

    out_dir: pathlib.Path
    ui: _UI
    dtype: type  # np.float64, or np.float32 with --float32
    clip: _Clip | None = None
    fk: _FKRun | None = None
    rows: list[tuple[str, str]] = dataclasses.field(default_factory=list)  # (step, summary) lines


def _demo_load(s: DemoState) -> None:
    cold = _load(None, s.ui, s.dtype)  # the first parse also compiles the jitted channel conversion
    s.clip = _load(None, _UI(quiet=True), s.dtype)
    m = s.clip.motion
    s.rows.append(("load", f"parse {s.clip.path.name}: {s.clip.skeleton.num_joints} joints, {m.num_frames} frames "
                           f"at {_num(m.fps)} fps"))
    s.rows.append(("", f"{_ms(cold.parse_seconds)} cold (compiles the channel conversion), "
                       f"{_ms(s.clip.parse_seconds)} warm"))


def _demo_fk(s: DemoState) -> None:
    s.fk = _clip_fk(s.clip, s.ui, repeats=_DEMO_TIMING_REPEATS + 1)
    f = s.clip.motion.num_frames
    s.rows.append(("fk", f"compile jit(vmap(forward_kinematics)) in {_ms(s.fk.compile_seconds)}"))
    s.rows.append(("", f"run {f} frames in one call: {_ms(s.fk.run_seconds)} = "
                       f"{s.fk.run_seconds / f * 1e6:.2f} µs per frame (median of {s.fk.repeats})"))


def _demo_save_fk(s: DemoState) -> None:
    out = s.out_dir / "demo_fk.npz"
    _save_npz(out, _fk_arrays(s.clip.skeleton, s.clip.motion, s.fk.result))
    s.rows.append(("save", f"wrote {out}"))


def _demo_plot(s: DemoState) -> None:
    frame = s.clip.motion.num_frames // 2
    out = s.out_dir / "demo_pose.png"
    try:
        import matplotlib  # noqa: F401  (optional: the plot extra)
    except ImportError:
        s.rows.append(("plot", "skipped: matplotlib is not installed (pip install 'jaxanim[plot]')"))
        return
    _plot(s.clip, frame, out)
    s.rows.append(("plot", f"wrote {out} (frame {frame})"))


#: The demo, in order: ``(name, step)``; a step reads and extends the :class:`DemoState`.
DEMO_STEPS: list[tuple[str, Callable[[DemoState], None]]] = [
    ("load the shipped clip", _demo_load),
    ("forward kinematics of every frame", _demo_fk),
    ("save the FK arrays", _demo_save_fk),
    ("plot a stick figure", _demo_plot),
]


def _cmd_demo(args: argparse.Namespace, ui: _UI) -> int:
    out_dir = pathlib.Path(args.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    state = DemoState(out_dir=out_dir, ui=ui, dtype=args.dtype)
    t_start = time.perf_counter()
    for i, (name, step) in enumerate(DEMO_STEPS, start=1):
        ui.progress(f"[{i}/{len(DEMO_STEPS)}] {name}")
        step(state)
    total = time.perf_counter() - t_start
    dev = jax.devices()[0]
    dtype = np.asarray(state.clip.motion.rotations).dtype
    lines = [f"jaxanim demo ({dtype}, {dev.platform}: {dev.device_kind})"]
    lines += [f"  {name:<5} {text}" for name, text in state.rows]
    lines.append(f"  total {_ms(total)}")
    ui.result("\n".join(lines))
    return 0
