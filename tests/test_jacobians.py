"""Analytic Jacobian against jax.jacfwd / jacrev of FK and finite differences on the manifold."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxanim
from jaxanim import rotations as rot

from .conftest import shared_bvh_files, shared_data_dir
from .helpers import assert_close, random_pose, shared_clip, small_skeleton

_ATOL_JAC = 1e-10  # relative to the size of the skeleton
STEMS = shared_bvh_files() or ["<shared data absent>"]


def _vee(W):
    return jnp.stack([W[..., 2, 1] - W[..., 1, 2], W[..., 0, 2] - W[..., 2, 0], W[..., 1, 0] - W[..., 0, 1]], -1) / 2


def autodiff_jacobian(skeleton, q, t, sites, mode=jax.jacfwd):
    """The reference: differentiate FK w.r.t. the same parameters (root translation, rotvec increments)."""
    idx = [skeleton.site_index(s) for s in sites]
    J = skeleton.num_joints

    def f(delta):
        q2, t2 = jaxanim.apply_increment(skeleton, q, t, delta)
        out = jaxanim.forward_kinematics(skeleton, q2, t2)
        pos = out.site_positions()[jnp.asarray(idx)]
        owner = [i if i < J else skeleton.end_site_parents[i - J] for i in idx]
        Rs = out.rotations[jnp.asarray(owner)]
        return pos, Rs

    delta0 = jnp.zeros(3 + 3 * J, q.dtype)
    dpos, dR = mode(f)(delta0)  # [S,3,cols], [S,3,3,cols]
    _, R0 = f(delta0)
    W = jnp.einsum("sabc,sdb->scad", dR, R0)  # [S, cols, 3, 3]: dR_c R0^T, skew
    omega = jnp.swapaxes(_vee(W), 1, 2)  # [S, 3, cols]
    return jnp.concatenate([dpos, omega], axis=1)


@functools.lru_cache(maxsize=None)
def _jit_pair(sites):
    ana = jax.jit(lambda sk, q, t: jaxanim.jacobian(sk, q, t, sites))
    ref = jax.jit(lambda sk, q, t: autodiff_jacobian(sk, q, t, sites))
    return ana, ref


@pytest.mark.parametrize("stem", STEMS)
def test_jacobian_equals_jacfwd_on_shared_skeletons(stem):
    shared_data_dir()
    skel, motion, _ = shared_clip(stem)
    # all End Sites plus the last joint (which has no End Site in the fairmotion clip)
    sites = tuple(skel.end_site_names) + (skel.names[-1], skel.names[0])
    ana, ref = _jit_pair(sites)
    scale = max(float(np.abs(np.asarray(skel.offsets)).sum()), 1.0)
    rotations, translations = np.asarray(motion.rotations), np.asarray(motion.translations)
    for frame in (0, motion.num_frames - 1):  # indexed on the host (eager indexing compiles a program each)
        q, t = jnp.asarray(rotations[frame]), jnp.asarray(translations[frame])
        A, B = ana(skel, q, t), ref(skel, q, t)
        assert A.shape == (len(sites), 6, 3 + 3 * skel.num_joints)
        assert_close(f"{stem} frame {frame} linear", A[:, :3], B[:, :3], atol=_ATOL_JAC * scale)
        assert_close(f"{stem} frame {frame} angular", A[:, 3:], B[:, 3:], atol=_ATOL_JAC)


_SMALL_SITES = ("head_End", "forearm_End", "leg", "arm")  # one jitted jacobian for the small skeleton's tests


def test_jacobian_matches_jacrev_and_finite_differences():
    skel = small_skeleton()
    q, t = random_pose(skel, 7)
    sites = _SMALL_SITES
    A = _jit_pair(sites)[0](skel, q, t)  # jitted (eager, its ~50 primitives compile one by one)
    B = jax.jit(lambda q, t: autodiff_jacobian(skel, q, t, sites, mode=jax.jacrev))(q, t)  # eager: op by op
    assert_close("jacrev", A, B, atol=1e-12)
    # central differences of the retraction, on the manifold
    eps = 1e-6
    idx = jnp.asarray([skel.site_index(s) for s in sites])
    owner = jnp.asarray([skel.site_index(s) if s in skel.names else skel.end_site_parents[skel.end_site_names.index(s)] for s in sites])
    cols = A.shape[-1]

    @jax.jit  # one program for every column (an eager loop dispatches each op of FK separately)
    def central(d):
        out_p = jaxanim.forward_kinematics(skel, *jaxanim.apply_increment(skel, q, t, d))
        out_m = jaxanim.forward_kinematics(skel, *jaxanim.apply_increment(skel, q, t, -d))
        dp = (out_p.site_positions()[idx] - out_m.site_positions()[idx]) / (2 * eps)
        dR = jnp.einsum("sab,scb->sac", out_p.rotations[owner], out_m.rotations[owner])
        return jnp.concatenate([dp, rot.matrix_to_rotvec(dR) / (2 * eps)], axis=-1)  # [sites, 6]

    fd = np.stack([np.asarray(central(jnp.asarray(np.eye(cols)[c] * eps))) for c in range(cols)], axis=-1)
    assert_close("finite differences", A, fd, atol=1e-8)


def test_jacobian_vmap_equals_loop():
    skel = small_skeleton()
    q, t = random_pose(skel, 8, n=4)
    sites = _SMALL_SITES
    # jitted, the vmap and the single call (eager, each op would compile on its own); the single call is the
    # program test_jacobian_matches_jacrev_and_finite_differences compiled, the poses are sliced on the host
    Jb = np.asarray(jax.jit(jax.vmap(lambda a, b: jaxanim.jacobian(skel, a, b, sites)))(q, t))
    one = _jit_pair(sites)[0]
    qs, ts = np.asarray(q), np.asarray(t)
    for i in range(4):
        assert_close(f"jacobian[{i}]", Jb[i], one(skel, jnp.asarray(qs[i]), jnp.asarray(ts[i])), atol=1e-15)


def test_jacobian_bad_input():
    skel = small_skeleton()
    q, t = random_pose(skel, 9)
    with pytest.raises(jaxanim.JaxanimError, match="unknown joint or End Site 'hand'; valid:"):
        jaxanim.jacobian(skel, q, t, ("hand",))
    with pytest.raises(jaxanim.JaxanimError, match="sites: expected a non-empty sequence"):
        jaxanim.jacobian(skel, q, t, ())
    with pytest.raises(jaxanim.JaxanimError, match=r"rotations: expected shape \(joints, 4\) = \(6, 4\)"):
        jaxanim.jacobian(skel, q[:, :3], t, ("leg",))
    with pytest.raises(jaxanim.JaxanimError, match=r"delta: expected shape \(3 \+ 3 \* joints,\) = \(21,\)"):
        jaxanim.apply_increment(skel, q, t, jnp.zeros(20))
    qn = np.array(q)
    # the jitted jacobian of the tests above (the eager call compiled ~60 primitives one by one: ~1.5 s)
    _jit_pair(_SMALL_SITES)[0](skel, q, t)
    np.testing.assert_array_equal(np.asarray(q), qn)
