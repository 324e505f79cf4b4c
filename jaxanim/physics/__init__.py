"""Rigid-body simulation in maximal coordinates: bodies and their mass properties, joints with
limits, ground contact, the model, the typed inputs of a step (Control), one step, rollouts and MJCF
export.
"""

from ._bodies import (
    BodyState as BodyState,
    RigidBodies as RigidBodies,
    SHAPES as SHAPES,
    angular_momentum as angular_momentum,
    bodies_center_of_mass as bodies_center_of_mass,
    box_inertia as box_inertia,
    capsule_inertia as capsule_inertia,
    force_at_point as force_at_point,
    kinetic_energy as kinetic_energy,
    linear_momentum as linear_momentum,
    make_bodies as make_bodies,
    make_state as make_state,
    potential_energy as potential_energy,
    shape_mass_properties as shape_mass_properties,
    sphere_inertia as sphere_inertia,
    step_free as step_free,
    world_inertia as world_inertia,
)
from ._joints import (
    JOINT_TYPES as JOINT_TYPES,
    Joints as Joints,
    joint_errors as joint_errors,
    joint_rows as joint_rows,
    limit_rows as limit_rows,
    make_joints as make_joints,
)
from ._contact import (
    CONTACT_MODELS as CONTACT_MODELS,
    Ground as Ground,
    contact_points as contact_points,
    make_ground as make_ground,
)
from ._control import (
    Control as Control,
    Servo as Servo,
    StablePD as StablePD,
)
from ._model import (
    PhysicsModel as PhysicsModel,
    joint_error as joint_error,
    make_model as make_model,
)
from ._step import spd_torques as spd_torques, step as step
from ._rollout import (
    Rollout as Rollout,
    SimResult as SimResult,
    rollout as rollout,
)
from ._mjcf import to_mjcf as to_mjcf
