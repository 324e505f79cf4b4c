"""Spread the leading batch axis of any pytree over all devices.

``shard_batch`` places every array leaf of a pytree on a one-dimensional device mesh, split along
its leading axis. A ``jax.jit`` of a ``jax.vmap``-ed function called on such arrays then runs on
every device in parallel (XLA partitions it automatically); the result is sharded the same way and
equals the unsharded one. The same code runs on one CPU, several GPUs, or several hosts under
``jax.distributed`` (there each process passes its own slice of the batch).
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding, PartitionSpec


def batch_mesh(devices: Sequence[jax.Device] | None = None, axis_name: str = "batch") -> Mesh:
    """A one-dimensional mesh over ``devices`` (default: all devices of all processes)."""
    devs = np.asarray(jax.devices() if devices is None else list(devices))
    return Mesh(devs, (axis_name,))


def batch_sharding(devices: Sequence[jax.Device] | None = None, axis_name: str = "batch") -> NamedSharding:
    """The sharding that splits axis 0 over ``devices`` and replicates the rest."""
    return NamedSharding(batch_mesh(devices, axis_name), PartitionSpec(axis_name))


def shard_batch(tree, *, devices: Sequence[jax.Device] | None = None, pad: bool = False):
    """Shard the leading axis of every array leaf of ``tree`` over ``devices``.

    Args:
        tree: a pytree whose array leaves all share the leading (batch) axis size ``B``. Non-array
            leaves (Python scalars, strings, static Module fields) are left alone. Under
            ``jax.distributed`` each process passes its local slice, every process the same number
            of rows ``B`` (checked: a collective over the processes); the result is the global
            array, process 0's rows first.
        devices: the devices to use (default: ``jax.devices()``, all processes).
        pad: if true and ``B`` is not a multiple of the device count, repeat the last row to the
            next multiple (slice the result back with ``[:B]``); if false such a ``B`` raises.
            Under ``jax.distributed`` each process pads its own slice to the same size (a multiple
            of its local devices, at least the largest slice), so slices may differ in size and
            each process's padding follows its own rows: process ``i``'s rows are
            ``out[i * n : i * n + B_i]`` with ``n = out.shape[0] // jax.process_count()``.

    Returns:
        A pytree of the same structure with ``jax.Array`` leaves sharded along axis 0.

    Raises:
        ValueError: if leaves disagree on the batch size, a leaf is a scalar, or (``pad`` false)
            ``B`` does not divide evenly over the devices or processes pass different ``B``.
    """
    sharding = batch_sharding(devices)
    multi = jax.process_count() > 1 and devices is None
    # rows this process holds must split evenly over the devices it feeds
    per = jax.local_device_count() if multi else sharding.mesh.size
    leaves = [x for x in jax.tree_util.tree_leaves(tree) if isinstance(x, (jax.Array, np.ndarray))]
    if not leaves:
        return tree
    sizes = set()
    for x in leaves:
        if np.ndim(x) == 0:
            raise ValueError(f"shard_batch: every array leaf needs a leading batch axis, got a scalar of shape {np.shape(x)}")
        sizes.add(np.shape(x)[0])
    if len(sizes) != 1:
        raise ValueError(f"shard_batch: array leaves disagree on the batch size (leading axis): {sorted(sizes)}")
    (B,) = sizes
    # under jax.distributed every process must build the same global shape: without this check,
    # unequal slices give each process its own idea of it and the first collective aborts them all
    B_all = [int(b) for b in np.ravel(multihost_utils.process_allgather(np.int32(B)))] if multi else [B]
    if len(set(B_all)) > 1 and not pad:
        raise ValueError(
            f"shard_batch: under jax.distributed every process passes the same number of rows; the processes "
            f"passed {B_all} (this is process {jax.process_index()}); pass pad=True to pad each to the largest"
        )
    if B % per:
        if not pad:
            raise ValueError(
                f"shard_batch: batch size {B} is not a multiple of the {per} devices; pass pad=True "
                f"or use a batch size divisible by {per}"
            )
    B_pad = -(-max(B_all) // per) * per

    def put(x):
        if not isinstance(x, (jax.Array, np.ndarray)):
            return x
        if B_pad != B:
            x = jnp.concatenate([jnp.asarray(x), jnp.repeat(jnp.asarray(x)[-1:], B_pad - B, axis=0)], axis=0)
        if multi:
            return jax.make_array_from_process_local_data(sharding, np.asarray(x))
        return jax.device_put(x, sharding)

    return jax.tree_util.tree_map(put, tree)
