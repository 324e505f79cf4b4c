"""Splines and keyframes: piecewise cubic curves (linear, cubic Hermite, Catmull-Rom, natural cubic
spline, piecewise Bezier; one Bezier curve of any degree), arc length and reparameterisation by arc
length, rotation curves on unit quaternions (slerp chains, squad) and keyframe interpolation of a
clip at new times. Every function solves one curve; batch with ``jax.vmap``.
"""

from ._curves import (
    PiecewiseCubic as PiecewiseCubic,
    bezier_curve as bezier_curve,
    bezier_spline as bezier_spline,
    catmull_rom_spline as catmull_rom_spline,
    catmull_rom_tangents as catmull_rom_tangents,
    evaluate as evaluate,
    hermite_spline as hermite_spline,
    linear_spline as linear_spline,
    natural_cubic_spline as natural_cubic_spline,
)
from ._arclength import (
    ArcLengthTable as ArcLengthTable,
    arc_length as arc_length,
    arc_length_table as arc_length_table,
    param_at_arc_length as param_at_arc_length,
    reparameterize_by_arc_length as reparameterize_by_arc_length,
)
from ._rotation_curves import (
    align_hemispheres as align_hemispheres,
    slerp_spline as slerp_spline,
    squad_spline as squad_spline,
)
from ._keyframes import (
    POSITION_METHODS as POSITION_METHODS,
    ROTATION_METHODS as ROTATION_METHODS,
    interpolate_motion as interpolate_motion,
)
