"""The 0.1 module paths (``jaxanim.fk``, ``jaxanim.rigid``, ``jaxanim.balance``, ...), kept working.

jaxanim 0.1 was one flat folder of modules; 0.2 groups them into subpackages. Each old module
name is registered as an alias of the private module that now holds its code, so
``import jaxanim.rigid``, ``from jaxanim.balance import balance_controller`` and
``jaxanim.fk.forward_kinematics`` still reach the same objects. Nothing else is converted here.
"""

from __future__ import annotations

import importlib
import sys

# old module (0.1) -> the module that holds its code now
MODULES = {
    "skeleton": None,  # a subpackage of the same name: nothing to alias
    "rotations": None,
    "ik": None,
    "physics": None,
    "character": None,
    "bvh": "skeleton._bvh",
    "motion": "skeleton._clips",
    "default_clip": "skeleton._default_clip",
    "fk": "kinematics._fk",
    "jacobians": "kinematics._jacobians",
    "limits": "kinematics._limits",
    "ik_ccd": "ik._ccd",
    "rigid": "physics._bodies",
    "joints": "physics._joints",
    "contact": "physics._contact",
    "control": "character._pd",
    "balance": "character._balance",
    "cli": "app._cli",
    "plot": "app._plot",
}


def register(package) -> None:
    """Make every 0.1 module path an alias of its new home (``sys.modules`` and an attribute)."""
    for old, new in MODULES.items():
        if new is None:
            continue
        module = importlib.import_module(f"{package.__name__}.{new}")
        sys.modules.setdefault(f"{package.__name__}.{old}", module)
        setattr(package, old, module)
