"""MuJoCo (C) and MJX as the peers of the ``physics`` benchmark, on jaxanim's exported MJCF (one MuJoCo body
per jaxanim body, framed at its center of mass, so ``xpos`` is ``BodyState.position``; a free joint on the root)."""

from __future__ import annotations

import contextlib
import io
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from . import PeerUnavailable, require

__all__ = ["MujocoSim", "load_mjx", "load_mujoco", "mjx_rollout"]


def load_mujoco():
    """The ``mujoco`` module, or :class:`PeerUnavailable`."""
    return require("mujoco", "pip install mujoco")


def load_mjx():
    """``mujoco.mjx``, or :class:`PeerUnavailable`; its import's warnings about the optional ``warp`` are muted."""
    load_mujoco()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        try:
            from mujoco import mjx
        except ImportError as exc:
            raise PeerUnavailable(f"cannot import mujoco.mjx: {exc} (pip install mujoco-mjx)") from exc
    return mjx


class MujocoSim:
    """A MuJoCo model (``xml``) of a jaxanim model and ``B`` characters' initial states, at rest in the assembly pose
    but for ``root_velocities [B, 3]`` (world, m/s) of the free body ``root``; positions in ``body_names`` order."""

    def __init__(self, xml: str, body_names: Sequence[str], root: int, root_velocities: np.ndarray):
        self.mujoco = mujoco = load_mujoco()
        self.model = mujoco.MjModel.from_xml_string(xml)
        self.ids = np.array([mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, n) for n in body_names])
        if np.any(self.ids < 0):
            raise PeerUnavailable("the MJCF lacks some of jaxanim's bodies")
        free = [j for j in range(self.model.njnt) if self.model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
        if len(free) != 1 or self.model.jnt_bodyid[free[0]] != self.ids[root]:
            raise PeerUnavailable("expected one free joint, on jaxanim's root body")
        self.root_dof = int(self.model.jnt_dofadr[free[0]])
        v = np.asarray(root_velocities, float).reshape(-1, 3)
        self.batch = v.shape[0]
        self.qpos0 = mujoco.MjData(self.model).qpos.copy()
        self.qvel0 = np.zeros((self.batch, self.model.nv))
        self.qvel0[:, self.root_dof:self.root_dof + 3] = v
        self.datas = [mujoco.MjData(self.model) for _ in range(self.batch)]
        self._spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        self.initial_states = np.empty((self.batch, mujoco.mj_stateSize(self.model, self._spec)))
        for i, state in enumerate(self.initial_states):
            mujoco.mj_getState(self.model, self.reset(i, mujoco.MjData(self.model)), state, self._spec)

    def reset(self, i: int, data=None):
        """Put character ``i``'s initial state into ``data`` (default its own ``MjData``)."""
        d = self.datas[i] if data is None else data
        self.mujoco.mj_resetData(self.model, d)
        d.qpos[:] = self.qpos0
        d.qvel[:] = self.qvel0[i]
        return d

    def step_loop(self, nstep: int, count: int) -> None:
        """Reset the first ``count`` characters and ``mj_step`` each ``nstep`` times."""
        step, m = self.mujoco.mj_step, self.model
        for i in range(count):
            d = self.reset(i)
            for _ in range(nstep):
                step(m, d)

    def rollout(self, nstep: int, pool: list, count: int) -> np.ndarray:
        """``[count, nstep, nstate]``: ``mujoco.rollout.rollout`` of ``count`` start states on ``pool``'s MjData."""
        from mujoco import rollout as mj_rollout

        return mj_rollout.rollout(self.model, pool, self.initial_states[:count], nstep=nstep, persistent_pool=True)[0]

    def positions(self, i: int = 0, *, state: np.ndarray | None = None, qpos: np.ndarray | None = None) -> np.ndarray:
        """Body positions ``[nb, 3]`` (jaxanim order) of character ``i`` now, of a physics ``state`` or at ``qpos``."""
        d = self.datas[i] if state is None and qpos is None else self.mujoco.MjData(self.model)
        if state is not None:
            self.mujoco.mj_setState(self.model, d, np.asarray(state, float), self._spec)
        if qpos is not None:
            d.qpos[:] = qpos
        self.mujoco.mj_kinematics(self.model, d)
        return d.xpos[self.ids].copy()


def mjx_rollout(sim: MujocoSim, nstep: int, batch: int) -> tuple[Callable, Any]:
    """``(jax.jit(jax.vmap(rollout)), batched mjx.Data)``: ``nstep`` ``mjx.step`` in a ``lax.scan`` per
    character over the first ``batch`` characters' initial states (cast to the dtypes ``mjx.step``
    returns: under x64 ``put_data`` makes int32 contact indices that ``step`` returns as int64)."""
    mjx = load_mjx()
    mx, datas = mjx.put_model(sim.model), []
    for i in range(batch):
        d = sim.reset(i, sim.mujoco.MjData(sim.model))
        sim.mujoco.mj_forward(sim.model, d)
        datas.append(mjx.put_data(sim.model, d))
    dx = jax.tree.map(lambda *a: jnp.stack(a), *datas)
    dx = jax.tree.map(lambda a, s: jnp.asarray(a, s.dtype), dx, jax.eval_shape(mjx.step, mx, datas[0]))

    def one(d):
        return jax.lax.scan(lambda c, _: (mjx.step(mx, c), None), d, None, length=nstep)[0].qpos

    return jax.jit(jax.vmap(one)), dx
