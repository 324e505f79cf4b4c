"""Motion-matching benchmark (``python -m benchmarks matching``): the exact nearest-neighbour search of
``jaxanim.matching`` for a batch of agents against a database of 100k+ frames synthesised from the shipped
walk, against faiss's exact ``IndexFlatL2`` (float32), a chunked NumPy brute force of the same expansion and
scipy's ``cKDTree`` on the same normalised features; and a crowd of agents animated by
``matching.motion_matching`` for 10 s, as time per frame."""

from __future__ import annotations

import dataclasses
import functools
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxanim import default_clip_path, matching, read_bvh
from jaxanim.app._simulate import _looped_motion
from jaxanim.skeleton import Motion, resample_at

from .peers import PeerUnavailable, require
from .report import Row, Table, Target, sel, usable_cores
from .timing import Runner

__all__ = ["ACCELERATOR_SIZES", "MatchingSizes", "crowd_inputs", "run_matching", "synthetic_database"]

_SEARCH = "jaxanim matching.search (vmap)"
_KDTREE = "scipy cKDTree.query (k=1)"
_NUMPY = "numpy brute force (BLAS)"
_FAISS = "faiss IndexFlatL2 (exact)"
_FAISS_HINT = "pip install faiss-cpu, in the bench extra"
#: The chunked NumPy search's block: queries x database rows (float64: 64 MiB, whatever the batch and database).
_NUMPY_QUERIES, _NUMPY_ROWS = 1024, 8192
_CROWD = "jaxanim matching.motion_matching (vmap)"


@dataclasses.dataclass(frozen=True)
class MatchingSizes:
    """Sizes (``--quick`` and tests shrink them): the walk's speeds and frames per speed (the database holds
    ``2 x speeds x frames`` rows with the mirror images), the search's agent batches, the crowd's agents (0: no
    crowd table) and seconds; the host peers search up to ``peer_max_batch`` agents (``None``: every batch)."""

    speeds: tuple[float, ...] = tuple(np.round(np.linspace(0.6, 1.6, 21), 3))
    frames_per_speed: int = 2400
    batches: tuple[int, ...] = (1024,)
    crowd: int = 1024
    crowd_seconds: float = 10.0
    peer_max_batch: int | None = None


#: ``--gpu`` on a machine with an accelerator: searches of 1,024 and 16,384 agents, a crowd of 16,384; the host
#: peers (faiss, NumPy, cKDTree) search at 1,024 only (their time per query does not depend on the batch), so that the
#: section's time budget reaches the crowd.
ACCELERATOR_SIZES = MatchingSizes(batches=(1024, 16384), crowd=16384, peer_max_batch=1024)


@functools.lru_cache(maxsize=4)
def synthetic_database(speeds: tuple[float, ...], frames: int, dtype: str = "float64") -> matching.MatchingDatabase:
    """The shipped walk looped and resampled to each speed factor (``frames`` frames each, at the walk's
    30 fps: speed ``s`` plays the loop ``s`` times as fast), and the mirror images of all."""
    skel, walk = read_bvh(default_clip_path())[:2]
    clips = []
    for s in speeds:
        long = _looped_motion(walk, int(np.ceil(frames * s)) + 2)
        m = resample_at(long, jnp.asarray(np.arange(frames) * s, dtype=long.rotations.dtype))
        clips.append(Motion(m.rotations, m.translations, walk.frame_time))
    return matching.build_database(clips, skel, mirror=True, dtype=jnp.dtype(dtype))


def _queries(db: matching.MatchingDatabase, n: int, seed: int = 0) -> np.ndarray:
    """Controller-like queries: a searchable row's pose features with another row's trajectory, plus noise."""
    rng = np.random.default_rng(seed)
    X = np.asarray(db.features, np.float64)
    ok = np.nonzero(np.asarray(db.searchable))[0]
    a, b = rng.choice(ok, n), rng.choice(ok, n)
    s = db.layout.trajectory_start
    q = np.concatenate([X[a, :s], X[b, s:]], axis=1)
    return q + 0.05 * rng.standard_normal(q.shape)


def _numpy_search(X: np.ndarray, sq: np.ndarray, Q: np.ndarray, queries: int = _NUMPY_QUERIES,
                  rows: int = _NUMPY_ROWS) -> tuple[np.ndarray, np.ndarray]:
    """Exact argmin of ``|q - x|^2 = |q|^2 - 2 q.x + |x|^2`` (``sq``: ``|x|^2``, ``inf`` on rows not to return),
    the expansion ``matching.search`` uses: per block of ``queries`` queries, one BLAS product per chunk of ``rows``
    database rows and a running argmin (the first row of a tie, as one argmin over all rows), so the distances held
    at once are one ``queries x rows`` block, whatever the database's size. Returns the rows and their squared
    distances by the expansion."""
    idx = np.empty(len(Q), np.int64)
    dist = np.empty(len(Q))
    for i in range(0, len(Q), queries):
        q = Q[i:i + queries]
        m2q = -2.0 * q
        block = np.empty((len(q), min(rows, len(X))))
        best, arg = np.full(len(q), np.inf), np.zeros(len(q), np.int64)
        for s in range(0, len(X), rows):
            x = X[s:s + rows]
            d = block[:, :len(x)]
            np.matmul(m2q, x.T, out=d)
            d += sq[s:s + rows]
            j = d.argmin(axis=1)
            v = d[np.arange(len(q)), j]
            better = v < best
            best, arg = np.where(better, v, best), np.where(better, j + s, arg)
        idx[i:i + queries] = arg
        dist[i:i + queries] = best + (q * q).sum(1)
    return idx, dist


def _faiss_available() -> bool:
    """Whether faiss imports here (the speed target then compares with it)."""
    try:
        require("faiss", _FAISS_HINT)
    except PeerUnavailable:
        return False
    return True


def _accuracy(X: np.ndarray, ok: np.ndarray, Q: np.ndarray, idx: np.ndarray, best: np.ndarray,
              dtype: str = "float64") -> tuple[float, float]:
    """Largest excess of the returned rows' true squared distance over the exact minimum, and the fraction
    of queries answered at the minimum to the dtype's round-off (``64 eps (2 |q|^2 + min + 1)``, 8x the search's
    tie window and the features' own rounding)."""
    d = ((Q - X[idx]) ** 2).sum(1)
    d = np.where(ok[idx], d, np.inf)
    excess = d - best
    tol = 64 * np.finfo(dtype).eps * (2.0 * (Q * Q).sum(1) + best + 1.0)
    return float(np.max(excess)), float(np.mean(excess <= tol))


def _search_table(config, sz: MatchingSizes) -> Table:
    db64 = synthetic_database(sz.speeds, sz.frames_per_speed)
    N, D = db64.features.shape
    searchable = int(np.sum(np.asarray(db64.searchable)))
    X = np.asarray(db64.features, np.float64)
    ok = np.asarray(db64.searchable)
    sq = np.where(ok, (X * X).sum(1), np.inf)
    batches = config.batches_for(sz.batches)
    # the speed target's batch: 1024, else the largest batch the host peers search
    tb = 1024 if 1024 in batches else max(
        [b for b in batches if sz.peer_max_batch is None or b <= sz.peer_max_batch] or batches)
    # The speed target's peer: the strongest like-for-like exact search, faiss IndexFlatL2 (float32, against
    # jaxanim's float32 row) where it runs here, else the chunked NumPy brute force (float64, against float64).
    vs_faiss = "float32" in config.dtypes and config.selects(_FAISS) and _faiss_available()
    if vs_faiss:
        speed = Target(f"jaxanim search at least as fast as faiss IndexFlatL2 at batch {tb} (both float32)",
                       sel(_SEARCH, "float32", tb), 1.0, versus=sel(_FAISS, "float32", tb))
    else:
        speed = Target(f"jaxanim search at least as fast as the chunked NumPy brute force at batch {tb} (both float64;"
                       " faiss is not run here)", sel(_SEARCH, "float64", tb), 1.0, versus=sel(_NUMPY, "float64", tb))
    table = Table(
        "matching-search", f"Motion matching: exact nearest-neighbour search, {N} database frames x agents",
        accuracy_label="max excess distance", description=(
            f"The database: the shipped walk looped and resampled to {len(sz.speeds)} speed factors "
            f"({min(sz.speeds):g}-{max(sz.speeds):g} x its {float(db64.mean_speed) / np.mean(sz.speeds):.2f} m/s; "
            f"{sz.frames_per_speed} frames each at 30 fps) and the mirror images of all: {N} frames, {searchable} "
            f"searchable (the last 1.5 s of each clip are not), {D} normalised, weighted features. Queries: a "
            "searchable row's pose features with another row's trajectory features, plus Gaussian noise (sigma "
            "0.05), as the controller asks. One timed call answers `batch` queries; **µs / char is per query**. "
            "Every implementation gets the same features and queries. "
            "jaxanim: `jax.vmap(matching.search)` (|q|^2 - 2 q.x + |x|^2 as one product [x, |x|^2] . [-2q, 1] per "
            "chunk of 512 rows, exact; compile apart). "
            "faiss: `IndexFlatL2` (faiss's standard exact search) on the searchable rows, k=1, with faiss's threads "
            f"set to the {usable_cores()} usable cores; faiss works in float32 only (features and queries are cast "
            "from the float64 set), so its row is float32 and stands beside jaxanim's float32 row, and both are "
            "judged at float32 round-off (building the index is in the compile column). "
            f"NumPy: the same expansion, one BLAS product per chunk of {_NUMPY_ROWS} database rows for blocks of "
            f"{_NUMPY_QUERIES} queries, keeping a running argmin (one {_NUMPY_QUERIES} x {_NUMPY_ROWS} float64 "
            "distance block in memory at a time), float64. "
            f"scipy: `cKDTree(features).query(Q, k=1, workers=-1)` on the same features (a k-d tree, which prunes "
            f"poorly in {D} dimensions; the tree's build time is in the compile column). "
            + ("The speed target compares jaxanim's float32 search with faiss IndexFlatL2, the strongest like-for-like "
               "peer (exact, brute force, float32). " if vs_faiss else
               "The speed target compares jaxanim's float64 search with the chunked NumPy brute force, the strongest "
               "like-for-like peer run here (exact, the same expansion, float64); faiss is not run in this "
               "configuration. ")
            + "Accuracy: the largest excess of a returned row's true squared distance over the exact minimum "
            "(float64 brute force); success: the fraction of queries answered at the minimum to the dtype's "
            "round-off (64 eps (2 |q|^2 + min + 1): 8x the search's tie window, for the expansion's own rounding), "
            "the same judge for every row."),
        targets=[speed, Target("every query exact (float64)", sel(_SEARCH, "float64"), 1.0, "success", worst=True)])
    run = Runner(config, table)
    exact: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    rows = np.nonzero(ok)[0]  # the searchable rows, which the faiss index and the tree hold

    def queries(b: int) -> np.ndarray:
        return _queries(db64, b)

    def best(b: int) -> np.ndarray:
        if b not in exact:
            exact[b] = _numpy_search(X, sq, queries(b))
        return exact[b][1]

    def gflops(b: int, seconds: float, n: int = N) -> str:
        return f"{b * n * D * 2 / seconds / 1e9:.1f} GFLOP/s in the distance products"

    def numpy_row(b: int) -> Row:
        Q = queries(b)
        (idx, _), tm = run.python(_numpy_search, X, sq, Q)
        err, succ = _accuracy(X, ok, Q, idx, best(b))
        return run.row(_NUMPY, "float64", b, tm, b, accuracy=err, success=succ,
                       note=f"chunked: {_NUMPY_QUERIES} queries x {_NUMPY_ROWS} rows per product; "
                            f"{gflops(b, tm.median)}")

    @functools.cache
    def faiss_index():
        faiss = require("faiss", _FAISS_HINT)
        faiss.omp_set_num_threads(usable_cores())
        t0 = time.perf_counter()
        index = faiss.IndexFlatL2(D)
        index.add(np.ascontiguousarray(X[ok], np.float32))
        return index, time.perf_counter() - t0, getattr(faiss, "__version__", "?")

    def faiss_row(b: int) -> Row:
        index, build, version = faiss_index()
        Q = queries(b)
        (_, j), tm = run.python(lambda q: index.search(q, 1), np.ascontiguousarray(Q, np.float32))
        err, succ = _accuracy(X, ok, Q, rows[j[:, 0]], best(b), "float32")
        return run.row(_FAISS, "float32", b, tm, b, build, err, success=succ,
                       note=f"faiss {version}, float32 only; index of the {len(rows)} searchable rows built in "
                            f"{build:.2f} s (compile column); {gflops(b, tm.median, len(rows))}")

    @functools.cache
    def kdtree():
        from scipy.spatial import cKDTree

        t0 = time.perf_counter()
        tree = cKDTree(X[ok])
        return tree, time.perf_counter() - t0

    def kd_row(b: int) -> Row:
        tree, build = kdtree()
        Q = queries(b)
        (_, j), tm = run.python(lambda q: tree.query(q, k=1, workers=-1), Q)
        err, succ = _accuracy(X, ok, Q, rows[j], best(b))
        return run.row(_KDTREE, "float64", b, tm, b, build, err, success=succ,
                       note=f"tree of the {len(rows)} searchable rows built in {build:.2f} s (compile column)")

    def jax_row(b: int, dtype: str) -> Row:
        db = synthetic_database(sz.speeds, sz.frames_per_speed, dtype)
        Q = jnp.asarray(queries(b), dtype)
        fn = jax.jit(jax.vmap(matching.search, in_axes=(None, 0)))
        res, tm, comp = run.jax(fn, db, Q)
        err, succ = _accuracy(X, ok, queries(b), np.asarray(res.index), best(b), dtype)
        return run.row(_SEARCH, dtype, b, tm, b, comp, err, success=succ, note=gflops(b, tm.median))

    for b in batches:
        run.add(_FAISS, "float32", b, functools.partial(faiss_row, b), peer=True, max_batch=sz.peer_max_batch)
        run.add(_NUMPY, "float64", b, functools.partial(numpy_row, b), peer=True, max_batch=sz.peer_max_batch)
        run.add(_KDTREE, "float64", b, functools.partial(kd_row, b), peer=True, max_batch=sz.peer_max_batch)
        for dt in config.dtypes:
            run.add(_SEARCH, dt, b, functools.partial(jax_row, b, dt))
    return table


def crowd_inputs(n: int, seconds: float, mean_speed: float, seed: int = 0) -> matching.ControlInput:
    """``n`` agents' inputs of 3 keys, batched ``[n, 3]``: a random heading and speed, then a turn of up to ±120°
    (about 2.1 rad) to another speed over 1 s from a random time. Agent ``i``'s five draws are the ``i``-th five of
    the seeded stream (the inputs of ``n`` agents are a prefix of any larger crowd's), vectorised over the agents:
    each equals ``matching.control_input`` of its keys (the velocity's direction as the facing, unwrapped)."""
    u = np.random.default_rng(seed).random((n, 5))  # what rng.uniform(lo, hi) draws, one after another
    yaw0 = -np.pi + (np.pi - -np.pi) * u[:, 0]
    yaw1 = yaw0 + (-2.1 + (2.1 - -2.1) * u[:, 1])
    s0, s1 = (mean_speed * (0.7 + (1.3 - 0.7) * u[:, k]) for k in (2, 3))
    t1 = (0.3 + (0.7 - 0.3) * u[:, 4]) * seconds
    heading = lambda yaw, s: s[:, None] * np.stack([np.sin(yaw), np.cos(yaw)], axis=-1)  # noqa: E731
    v = np.stack([heading(yaw0, s0), heading(yaw0, s0), heading(yaw1, s1)], axis=1)  # [n, 3, 2]
    times = np.stack([np.zeros(n), t1, t1 + 1.0], axis=1)
    yaw = np.unwrap(np.arctan2(v[..., 0], v[..., 1]), axis=1)
    one = matching.control_input([0.0, 1.0, 2.0], np.ones((3, 2)))  # the structure (checks hold by construction)
    return eqx.tree_at(lambda c: (c.times, c.velocity, c.yaw), one,
                       tuple(jnp.asarray(x, one.times.dtype) for x in (times, v, yaw)))


def _crowd_table(config, sz: MatchingSizes) -> Table:
    db = synthetic_database(sz.speeds, sz.frames_per_speed)
    frames = int(round(sz.crowd_seconds / float(db.frame_time))) + 1
    n = sz.crowd
    table = Table(
        "matching-crowd", f"Motion matching: a crowd of {n} agents for {sz.crowd_seconds:g} s",
        accuracy_label="heading error (deg)", description=(
            f"`jax.vmap(matching.motion_matching)` over {n} agents on the {db.num_rows}-frame database of the "
            f"search table: {frames} frames at 30 fps in one compiled `lax.scan`, searches every 0.15 s and on "
            "sharp input changes (the batched search runs on the frames where some agent needs one: ~1 in 4 "
            "here), inertialized switches. Each agent's input: a random heading and speed (0.7-1.3 x the "
            "database's mean), then a turn of up to ±120° to another speed over 1 s at a random time. **µs / "
            "char is per agent-frame**; the note gives the time per frame of the whole crowd. Accuracy: the "
            "mean over agents of the angle between the last 1.5 s of root motion and the input's final heading; "
            "success: agents whose speed over that time is within 25 % of the input's and heading within 20°. "
            "No peer: the search table compares the search."),
        targets=[Target("crowd ≤ 33 ms per frame (real time at 30 fps)", sel(_CROWD), 33e3 / n)])
    run = Runner(config, table)
    inputs = crowd_inputs(n, sz.crowd_seconds, float(db.mean_speed))

    def row(dtype: str) -> Row:
        d = db if dtype == "float64" else synthetic_database(sz.speeds, sz.frames_per_speed, dtype)
        inp = jax.tree.map(lambda x: x.astype(dtype), inputs)
        fn = jax.jit(jax.vmap(lambda dbase, i: matching.motion_matching(dbase, i, frames), in_axes=(None, 0)))
        res, tm, comp = run.jax(fn, d, inp)
        root = np.asarray(res.motion.translations[:, :, 0], np.float64)
        k = min(int(round(1.5 / float(db.frame_time))), frames - 1)
        moved = root[:, -1, [0, 2]] - root[:, -1 - k, [0, 2]]
        heading = np.arctan2(moved[:, 0], moved[:, 1])
        want = np.asarray(inputs.yaw[:, -1], np.float64)
        err = np.degrees(np.abs(np.arctan2(np.sin(heading - want), np.cos(heading - want))))
        speed = np.linalg.norm(moved, axis=1) / (k * float(db.frame_time))
        want_speed = np.linalg.norm(np.asarray(inputs.velocity[:, -1], np.float64), axis=1)
        ok = (np.abs(speed - want_speed) <= 0.25 * want_speed) & (err <= 20.0)
        searches = float(np.asarray(res.searched).any(axis=0).mean())
        return run.row(_CROWD, dtype, n, tm, n * (frames - 1), comp, float(err.mean()), success=float(ok.mean()),
                       note=f"{tm.median / (frames - 1) * 1e3:.2f} ms per frame for {n} agents; a batched search on "
                            f"{100 * searches:.0f} % of the frames; {int(np.asarray(res.switched).sum())} switches")

    for dt in config.dtypes:
        run.add(_CROWD, dt, n, functools.partial(row, dt))
    return table


def run_matching(config, sizes: MatchingSizes | None = None) -> list[Table]:
    """The ``matching`` benchmark (see the module docstring); ``sizes`` shrinks it for tests."""
    sz = sizes or config.pick(MatchingSizes(), accelerator=ACCELERATOR_SIZES, quick=MatchingSizes(
        speeds=(0.8, 1.2), frames_per_speed=300, batches=(8,), crowd=8, crowd_seconds=2.0))
    return [_search_table(config, sz)] + ([_crowd_table(config, sz)] if sz.crowd > 0 else [])
