"""solvers: generic numerics (least squares, LQR, iLQR, DDP, batching helpers).

This package knows nothing of skeletons and never imports ``jaxanim``.
"""

from ._sharding import batch_mesh as batch_mesh, batch_sharding as batch_sharding, shard_batch as shard_batch
