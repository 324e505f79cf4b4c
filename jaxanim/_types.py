"""jaxtyping aliases and the dimension names used across jaxanim.

Dimension glossary (the same names in every docstring and jaxtyping annotation):
    joints      number of joints of a skeleton (End Sites excluded)
    end_sites   number of End Sites
    sites       targets or Jacobian sites (joints or End Sites)
    frames      frames of a motion clip
    cols        pose-parameter columns of a Jacobian: 3 (root translation) + 3 * joints
    bodies      rigid bodies of a physics model
    T           horizon (time steps) of a trajectory
    n, m        state and control dimensions (solvers); rows and unknowns of least squares
    *batch      any leading axes (rotation helpers only)
"""

from jaxtyping import Array, ArrayLike, Bool, Float, Int, Shaped

__all__ = ["Array", "ArrayLike", "Bool", "Float", "Int", "Shaped"]
