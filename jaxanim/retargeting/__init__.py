"""Retargeting human motion onto robots: the map and its calibration, the whole-clip problem
(:func:`prepare_retarget`), its solve (:func:`solve_retarget`: one least-squares problem per clip,
feet planted, joint ranges as hard bounds), batches of clips (:func:`retarget_clips`) and the
diagnostics (:func:`diagnostics`, :func:`summary`). A retargeted clip is written in the policy trainers'
motion formats (LAFAN1 csv, BeyondMimic / mjlab npz, GMR pickle) by :func:`write_motion`.

The robot itself (loading, kinematics, the tangent layout) is :mod:`jaxanim.robots`; loading needs
the optional extra: ``pip install 'jaxanim[robots]'``.
"""

from ..robots._data import default_mapping_path as default_mapping_path
from ._mapping import (
    Calibration as Calibration,
    RetargetMap as RetargetMap,
    calibrate as calibrate,
    load_mapping as load_mapping,
    upright as upright,
    with_soles as with_soles,
)
from ._problem import (
    RetargetProblem as RetargetProblem,
    prepare_retarget as prepare_retarget,
    prepared_robot as prepared_robot,
    stack_problems as stack_problems,
)
from ._solve import RetargetOptions as RetargetOptions, RetargetResult as RetargetResult, solve_retarget as solve_retarget
from ._diagnostics import RetargetDiagnostics as RetargetDiagnostics, diagnostics as diagnostics, summary as summary
from ._retarget import retarget as retarget, retarget_clips as retarget_clips
from ._auto_map import auto_map as auto_map, auto_map_dict as auto_map_dict
from ._export import (
    FORMATS as FORMATS,
    format_suffix as format_suffix,
    qvel_from_qpos as qvel_from_qpos,
    resample_qpos as resample_qpos,
    write_motion as write_motion,
)
