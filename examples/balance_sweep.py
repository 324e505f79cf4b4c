"""Sweep static balance over (k_p, k_d, push force) with one vmapped rollout; write a fall map PNG.

The character is built in a BVH clip's first frame (its soles fitted to that frame, see
:func:`jaxanim.character.build_character`) and holds it by stable PD plus the Jacobian-transpose balance law
of :func:`jaxanim.balance.balance_controller` (no root force). Every grid point gets a horizontal
push on the torso; a point "falls" when the center of mass drops below 95 % of its start height
(:func:`jaxanim.balance.stood`) or the rollout is stopped. All gains and the push are arrays in
the controller's ``args``, so the whole grid is one ``jax.vmap`` of one compiled rollout.

    python examples/balance_sweep.py --out balance_sweep.png --seconds 5 --grid 4 4 3
"""

from __future__ import annotations

import argparse
import pathlib

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import jaxanim  # noqa: E402
from jaxanim import balance, character, contact, physics  # noqa: E402

DEFAULT_BVH = pathlib.Path(__file__).resolve().parents[1].parent / "shared" / "data" / "bvh" / "cmu_01_01_trim300.bvh"


def setup(bvh: pathlib.Path, dt: float, push_body: str, push_start: float, push_duration: float):
    """The character, its standing state and the balance controller for the clip's first frame."""
    skel, motion = jaxanim.read_bvh(bvh)[:2]
    q0, t0 = motion.rotations[0], motion.translations[0]
    char, _ = character.build_character(skel, q0, t0, ground=contact.make_ground("complementarity"))
    state = character.character_state(char, q0, t0)
    ctrl, args = balance.balance_controller(char, q0, t0, dt, push=(np.zeros(3), push_body, push_start, push_duration))
    return char, state, ctrl, args


def sweep(char, state, ctrl, args, dt, num_steps, kps, kds, pushes, direction, *, record_every=6):
    """``stood [len(kps), len(kds), len(pushes)]`` (bool) and the result codes, one vmapped rollout."""
    K, D, P = np.meshgrid(kps, kds, pushes, indexing="ij")
    n = K.size
    batch = {k: jnp.broadcast_to(v, (n,) + v.shape) for k, v in args.items()}
    batch["balance_kp"] = jnp.asarray(K.ravel())
    batch["balance_kd"] = jnp.asarray(D.ravel())
    batch["push_force"] = jnp.asarray(P.ravel()[:, None] * np.asarray(direction, float)[None, :])

    def one(a):
        run = physics.rollout(char.model, state, dt, num_steps, record_every=record_every, controller=ctrl,
                              controller_args=a)
        ok = balance.stood(char, state, run.trajectory) & (run.result == physics.SimResult.successful)
        return ok

    ok = jax.vmap(one)(batch)
    return np.asarray(ok).reshape(K.shape)


def plot(stood, kps, kds, pushes, out: pathlib.Path, title: str):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap

    P = len(pushes)
    fig, axes = plt.subplots(1, P, figsize=(3.2 * P + 0.6, 3.2), squeeze=False, constrained_layout=True)
    cmap = ListedColormap(["#d62728", "#2ca02c"])
    for i, ax in enumerate(axes[0]):
        ax.imshow(stood[:, :, i].T.astype(float), origin="lower", cmap=cmap, vmin=0, vmax=1, aspect="auto",
                  extent=(-0.5, len(kps) - 0.5, -0.5, len(kds) - 0.5))
        ax.set_xticks(range(len(kps)), [f"{v:g}" for v in kps], rotation=45)
        ax.set_yticks(range(len(kds)), [f"{v:g}" for v in kds])
        ax.set_xlabel("balance k_p (N/m)")
        if i == 0:
            ax.set_ylabel("balance k_d (N s/m)")
        ax.set_title(f"push {pushes[i]:g} N")
    fig.suptitle(title + "  (green: stands, red: falls)", fontsize=9)
    fig.savefig(out, dpi=100)
    plt.close(fig)


def main(argv=None) -> np.ndarray:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--bvh", type=pathlib.Path, default=DEFAULT_BVH, help="clip whose first frame stands")
    p.add_argument("--out", type=pathlib.Path, default=pathlib.Path("balance_sweep.png"), help="output PNG")
    p.add_argument("--seconds", type=float, default=5.0, help="simulated time per grid point")
    p.add_argument("--dt", type=float, default=1 / 120, help="step, s (the notes' 120 Hz control rate)")
    p.add_argument("--grid", type=int, nargs=3, default=(4, 4, 3), metavar=("NKP", "NKD", "NPUSH"),
                   help="grid sizes over balance k_p, k_d and push force")
    p.add_argument("--kp-max", type=float, default=6000.0, help="largest balance k_p, N/m (grid from 0)")
    p.add_argument("--kd-max", type=float, default=1200.0, help="largest balance k_d, N s/m (grid from 0)")
    p.add_argument("--push-min", type=float, default=100.0, help="smallest push, N")
    p.add_argument("--push-max", type=float, default=250.0, help="largest push, N")
    p.add_argument("--push-direction", type=float, nargs=3, default=(0.0, 0.0, 1.0),
                   help="horizontal push direction, world frame (default +Z: forwards, heels to toes, for the CMU clip)")
    p.add_argument("--push-body", default="Spine", help="body pushed (its center of mass)")
    p.add_argument("--push-start", type=float, default=0.5, help="push start, s")
    p.add_argument("--push-duration", type=float, default=0.2, help="push duration, s")
    a = p.parse_args(argv)
    if not a.bvh.is_file():
        p.error(f"--bvh: no such file {a.bvh}")
    nkp, nkd, npush = a.grid
    if min(a.grid) < 1:
        p.error("--grid: sizes must be >= 1")
    d = np.asarray(a.push_direction, float)
    if not np.linalg.norm(d) > 0:
        p.error("--push-direction: a non-zero vector")
    d = d / np.linalg.norm(d)
    num_steps = max(1, int(round(a.seconds / a.dt)))
    record_every = 6 if num_steps % 6 == 0 else 1
    kps = np.linspace(0.0, a.kp_max, nkp)
    kds = np.linspace(0.0, a.kd_max, nkd)
    pushes = np.linspace(a.push_min, a.push_max, npush)
    char, state, ctrl, args = setup(a.bvh, a.dt, a.push_body, a.push_start, a.push_duration)
    ok = sweep(char, state, ctrl, args, a.dt, num_steps, kps, kds, pushes, d, record_every=record_every)
    plot(ok, kps, kds, pushes, a.out,
         f"{a.bvh.name}: {a.seconds:g} s, push on {a.push_body} {a.push_duration:g} s from t={a.push_start:g} s")
    for i, f in enumerate(pushes):
        print(f"push {f:g} N: stands at {int(ok[:, :, i].sum())} of {nkp * nkd} (k_p, k_d) points")
    print(f"wrote {a.out}")
    return ok


if __name__ == "__main__":
    main()
