"""jaxtyping aliases and the dimension names used across jaxanim.

Dimension glossary:
    joints      number of joints of a skeleton (End Sites excluded)
    end_sites   number of End Sites
    frames      frames of a motion clip
    cols        pose-parameter columns of a Jacobian: 3 (root translation) + 3 * joints
    *batch      any leading axes (rotation helpers only)
"""

from jaxtyping import Array, ArrayLike, Bool, Float, Int, Shaped

__all__ = ["Array", "ArrayLike", "Bool", "Float", "Int", "Shaped"]
