"""Batch sharding over devices: two forced host devices give the unsharded result."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import solvers

from .conftest import REPO

_SCRIPT = textwrap.dedent(
    """
    import jax, jax.numpy as jnp, numpy as np
    jax.config.update("jax_enable_x64", True)
    import jaxanim
    from tests.helpers import random_pose, small_skeleton
    assert len(jax.devices()) == 2, jax.devices()
    skel = small_skeleton()
    q, t = random_pose(skel, 0, n=8)
    fk = jax.jit(jax.vmap(jaxanim.forward_kinematics, in_axes=(None, 0, 0)))
    ref = fk(skel, q, t)
    qs, ts = jaxanim.shard_batch((q, t))
    assert len(qs.sharding.device_set) == 2
    out = fk(skel, qs, ts)
    assert len(out.positions.sharding.device_set) == 2, out.positions.sharding
    np.testing.assert_array_equal(np.asarray(out.positions), np.asarray(ref.positions))
    np.testing.assert_array_equal(np.asarray(out.rotations), np.asarray(ref.rotations))
    # odd batch: padded, then sliced back
    qp, tp = jaxanim.shard_batch((q[:7], t[:7]), pad=True)
    assert qp.shape[0] == 8
    np.testing.assert_array_equal(np.asarray(fk(skel, qp, tp).positions[:7]), np.asarray(ref.positions[:7]))
    try:
        jaxanim.shard_batch((q[:7], t[:7]))
    except ValueError as e:
        assert "not a multiple of the 2 devices" in str(e)
    else:
        raise AssertionError("expected ValueError")
    print("SHARDING-OK")
    """
)


def test_sharded_equals_unsharded_on_two_host_devices():
    env = dict(os.environ)
    env["XLA_FLAGS"] = (env.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2").strip()
    env["JAX_PLATFORMS"] = "cpu"
    res = subprocess.run([sys.executable, "-c", _SCRIPT], cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    assert "SHARDING-OK" in res.stdout


def test_shard_batch_single_device_and_errors():
    x = {"a": jnp.arange(6.0).reshape(3, 2), "b": np.ones(3), "name": "static"}
    out = solvers.shard_batch(x)
    assert out["name"] == "static"
    np.testing.assert_array_equal(np.asarray(out["a"]), np.asarray(x["a"]))
    with pytest.raises(ValueError, match="disagree on the batch size"):
        solvers.shard_batch({"a": jnp.zeros(3), "b": jnp.zeros(4)})
    with pytest.raises(ValueError, match="needs a leading batch axis"):
        solvers.shard_batch({"a": jnp.zeros(())})
    assert solvers.batch_mesh().size == len(jax.devices())
