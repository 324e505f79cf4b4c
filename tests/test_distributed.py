"""Scale-out under ``jax.distributed``: 2 processes on localhost, a batch sharded across them with
``shard_batch``, the same result as one process.

Each test starts 2 Python subprocesses on the CPU platform (coordinator 127.0.0.1 on a free port).
Each process passes its own slice of the batch to ``shard_batch``, runs jitted vmapped public
functions (``forward_kinematics``; ``solvers.dare``, whose adaptive ``while_loop`` needs a
cross-device reduction over the batch) on the global array, gathers the output with
``process_allgather`` and compares it with the unsharded batch computed on its own device. The
comparison is exact: every batch row goes through the same per-row operations in either layout (FK
is elementwise along the batch; a DARE problem that has converged is frozen, so its value does not
depend on how long the rest of the batch iterates), so sharding changes which device computes a
row, not its arithmetic. Every process is killed if one fails or the pair outlives the timeout.
"""

from __future__ import annotations

import json
import sys
import textwrap

import pytest

from benchmarks.scaling import check_processes, free_port, run_processes, subprocess_env

_TIMEOUT_S = 120.0  # each pair takes ~6 s on 2 idle cores; generous for a loaded CI machine

_WORKER = textwrap.dedent(
    """
    import json, sys
    spec = json.loads(sys.argv[1])
    pid, local = spec["process_id"], spec["local_devices"]
    import jax
    jax.config.update("jax_enable_x64", True)
    # cross-process collectives on the CPU backend (the while loop's reduction, process_allgather)
    # need an implementation: gloo is jax 0.10's default, named so that a default of "none" fails loudly
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.distributed.initialize(coordinator_address=f"127.0.0.1:{spec['port']}", num_processes=2,
                               process_id=pid, initialization_timeout=60)
    import numpy as np
    from jax.experimental.multihost_utils import process_allgather
    import jaxanim, solvers
    from benchmarks.oc import make_dare_systems
    from tests.helpers import random_pose, small_skeleton

    assert jax.process_count() == 2 and jax.local_device_count() == local, (jax.process_count(), jax.devices())
    assert jax.device_count() == 2 * local, jax.devices()

    def local_slice(tree, B):  # this process's rows of a global batch of B
        return jax.tree.map(lambda x: np.asarray(x)[pid * B // 2:(pid + 1) * B // 2], tree)

    def check(name, fn, consts, batch, B):
        ref = fn(*consts, *batch)  # one process: the whole batch on this process's first device
        out = fn(*consts, *jaxanim.shard_batch(local_slice(batch, B)))
        for leaf in jax.tree.leaves(out):
            assert len(leaf.sharding.device_set) == 2 * local and not leaf.is_fully_addressable, (name, leaf.sharding)
        got = process_allgather(out, tiled=True)
        for (path, g), r in zip(jax.tree_util.tree_leaves_with_path(got), jax.tree.leaves(ref)):
            np.testing.assert_array_equal(g, np.asarray(r), err_msg=f"{name}{jax.tree_util.keystr(path)}")

    skel = small_skeleton()
    B = 8 * local
    fk = jax.jit(jax.vmap(jaxanim.forward_kinematics, in_axes=(None, 0, 0)))
    q, t = (np.asarray(x) for x in random_pose(skel, 0, n=B))  # on the host: sliced below without compiling
    check("forward_kinematics", fk, (skel,), (q, t), B)
    dare = jax.jit(jax.vmap(lambda A, B, Q, R: solvers.dare(A, B, Q, R)))
    check("dare", dare, (), make_dare_systems(B, 3, 2), B)
    # slices of different sizes (B/2 - 1 and B/2 - 2 rows of the batch above): refused, or with
    # pad=True each padded to the same size after its own rows (B/2 - 1 rows, B/2 with 2 devices a
    # process): the global batch of the checks above, so both FK programs are reused, not compiled
    k0, k1 = B // 2 - 1, B // 2 - 2
    mine = (q[:k0], t[:k0]) if pid == 0 else (q[k0:k0 + k1], t[k0:k0 + k1])
    try:
        jaxanim.shard_batch(mine)
    except ValueError as e:
        assert f"the processes passed [{k0}, {k1}]" in str(e), e
    else:
        raise AssertionError("unequal slices without pad: expected ValueError")
    qs, ts = jaxanim.shard_batch(mine, pad=True)
    n = qs.shape[0] // 2
    assert n == (k0 if local == 1 else B // 2), qs.shape
    got = process_allgather(fk(skel, qs, ts).positions, tiled=True)
    want = np.asarray(fk(skel, q, t).positions)[:k0 + k1]
    np.testing.assert_array_equal(np.concatenate([got[:k0], got[n:n + k1]]), want,
                                  err_msg="pad=True: each process's rows at the start of its part")
    print("DISTRIBUTED-OK", json.dumps({"process": pid, "devices": jax.device_count()}))
    jax.distributed.shutdown()
    """
)


def test_two_processes_give_the_one_process_result():
    """2 processes with 2 CPU devices each: the batch is sharded across processes and across each
    process's devices. One device a process, the plain multi-host layout, is the scaling benchmark's
    2-process layout, whose FK test_benchmarks_scaling.py checks against one process (a second
    pair here cost 14 s of the suite for no other code path)."""
    local_devices = 2
    port = free_port()
    specs = [json.dumps({"process_id": i, "port": port, "local_devices": local_devices}) for i in range(2)]
    results = run_processes([[sys.executable, "-c", _WORKER, s] for s in specs],
                            env=subprocess_env(local_devices), timeout_s=_TIMEOUT_S)
    check_processes(results, f"2 processes x {local_devices} device(s) on 127.0.0.1:{port}")
    for i, r in enumerate(results):
        assert "DISTRIBUTED-OK" in r.stdout, f"process {i} did not finish its checks:\n{r.stdout[-2000:]}"


def test_a_failing_process_stops_its_peer_with_its_stderr():
    """The launcher kills the rest of the group when one process fails, and reports its stderr."""
    port = free_port()
    wait = (f"import jax; jax.distributed.initialize(coordinator_address='127.0.0.1:{port}', num_processes=2, "
            "process_id=0, initialization_timeout=60)")
    results = run_processes([[sys.executable, "-c", wait], [sys.executable, "-c", "raise SystemExit('peer died')"]],
                            env=subprocess_env(), timeout_s=_TIMEOUT_S)
    assert results[1].returncode == 1 and results[0].returncode != 0 and not results[0].timed_out, results
    with pytest.raises(RuntimeError, match="(?s)process 1 exit status 1.*peer died"):
        check_processes(results, "demo")
