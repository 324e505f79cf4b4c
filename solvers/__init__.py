"""solvers: generic numerics (least squares, LQR, iLQR, DDP, MPC, test problems, batching helpers).

This package knows nothing of skeletons and never imports ``jaxanim``.
"""

from ._sharding import batch_mesh as batch_mesh, batch_sharding as batch_sharding, shard_batch as shard_batch
from ._lanes import lane_map as lane_map, repeat_while as repeat_while
from ._results import RESULTS as RESULTS, Solution as Solution
from ._least_squares import (
    AbstractLeastSquaresSolver as AbstractLeastSquaresSolver,
    GaussNewton as GaussNewton,
    GradientDescent as GradientDescent,
    JaxoptSolver as JaxoptSolver,
    LevenbergMarquardt as LevenbergMarquardt,
    OptimistixSolver as OptimistixSolver,
    least_squares as least_squares,
)
from ._banded import (
    block_pentadiagonal_solve as block_pentadiagonal_solve,
    block_tridiagonal_solve as block_tridiagonal_solve,
)
from .lqr import LQRSolution as LQRSolution, lqr as lqr
from ._riccati import RiccatiSolution as RiccatiSolution, care as care, dare as dare
from .ilqr import ILQROptions as ILQROptions, TrajectorySolution as TrajectorySolution, ddp as ddp, ilqr as ilqr
from .mpc import MPCSolution as MPCSolution, mpc as mpc, mpc_step as mpc_step, shift_controls as shift_controls
from . import problems as problems
