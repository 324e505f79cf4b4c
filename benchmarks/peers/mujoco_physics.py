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
    but for ``root_velocities [B, 3]`` (world, m/s) of the free body ``root``; positions in ``body_names`` order.
    The initial states are one state with each character's root velocity written in (no ``MjData`` per character),
    and a character's ``MjData`` is made when first used: 65,536 characters cost a ``[B, nstate]`` array."""

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
        self._datas: dict[int, Any] = {}
        self._spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        # the state vector is [time, qpos, qvel, ...] (mjtState's bit order): character i's is the rest state
        # with its qvel written in
        rest = np.empty(mujoco.mj_stateSize(self.model, self._spec))
        d = mujoco.MjData(self.model)
        mujoco.mj_resetData(self.model, d)
        d.qpos[:] = self.qpos0
        mujoco.mj_getState(self.model, d, rest, self._spec)
        lo = mujoco.mj_stateSize(self.model, mujoco.mjtState.mjSTATE_TIME | mujoco.mjtState.mjSTATE_QPOS)
        self.initial_states = np.repeat(rest[None], self.batch, axis=0)
        self.initial_states[:, lo:lo + self.model.nv] = self.qvel0

    def data(self, i: int):
        """Character ``i``'s own ``MjData`` (made on first use)."""
        if i not in self._datas:
            self._datas[i] = self.mujoco.MjData(self.model)
        return self._datas[i]

    def reset(self, i: int, data=None):
        """Put character ``i``'s initial state into ``data`` (default its own ``MjData``)."""
        d = self.data(i) if data is None else data
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
        d = self.data(i) if state is None and qpos is None else self.mujoco.MjData(self.model)
        if state is not None:
            self.mujoco.mj_setState(self.model, d, np.asarray(state, float), self._spec)
        if qpos is not None:
            d.qpos[:] = qpos
        self.mujoco.mj_kinematics(self.model, d)
        return d.xpos[self.ids].copy()


def mjx_rollout(sim: MujocoSim, nstep: int, batch: int) -> tuple[Callable, Any, jax.Array]:
    """``(jax.jit(jax.vmap(rollout)), mjx.Data, qvel [batch, nv])``: ``nstep`` ``mjx.step`` in a ``lax.scan`` per
    character from the first ``batch`` characters' initial states. The characters differ only in ``qvel``, so
    one ``mjx.Data`` (character 0's after ``mj_forward``, cast to the dtypes ``mjx.step`` returns: under x64
    ``put_data`` makes int32 contact indices that ``step`` returns as int64) is shared (``in_axes=None``) and each
    character's starts as it with its ``qvel``; ``mjx.step`` recomputes everything else from ``qpos``, ``qvel`` and
    the warm start (zero for every character)."""
    mjx = load_mjx()
    mx = mjx.put_model(sim.model)
    d = sim.reset(0, sim.mujoco.MjData(sim.model))
    sim.mujoco.mj_forward(sim.model, d)
    dx = mjx.put_data(sim.model, d)
    dx = jax.tree.map(lambda a, s: jnp.asarray(a, s.dtype), dx, jax.eval_shape(mjx.step, mx, dx))

    def one(d0, qvel):
        d = d0.replace(qvel=qvel)
        return jax.lax.scan(lambda c, _: (mjx.step(mx, c), None), d, None, length=nstep)[0].qpos

    return jax.jit(jax.vmap(one, in_axes=(None, 0))), dx, jnp.asarray(sim.qvel0[:batch], dx.qvel.dtype)
