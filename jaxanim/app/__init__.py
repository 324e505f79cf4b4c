"""The command line (``jaxanim info | fk | plot | ik | simulate | demo``) and plots.
"""

from ._cli import (
    main as main,
)
from ._plot import (
    plot_pose as plot_pose,
    save_pose_png as save_pose_png,
)
