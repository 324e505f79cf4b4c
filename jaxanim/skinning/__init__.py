"""Skinning: linear blend (LBS) and dual-quaternion (DQS) skinning of one pose (batch with
``jax.vmap``), bind transforms, skin weights (the distance-to-bone heuristic and their checks), a
procedural capsule skin for any skeleton, and OBJ reading and writing.
"""

from ._bind import bind_transforms as bind_transforms
from ._mesh import (
    Mesh as Mesh,
    SkinWeights as SkinWeights,
    capsule_mesh as capsule_mesh,
    check_weights as check_weights,
)
from ._weights import heuristic_weights as heuristic_weights
from ._skin import (
    METHODS as METHODS,
    skin as skin,
    skin_motion as skin_motion,
)
from ._obj import (
    OBJParseError as OBJParseError,
    read_obj as read_obj,
    write_obj as write_obj,
)
