"""Kinematics of the motion platforms: the 6-RUS rotary platform, the 6-UPS Stewart platform
(linear actuators) and the planar 3-RRR robot."""

from motionbase.physics import rotation_matrix
from motionbase.platform.calibration import CursorCalibration
from motionbase.platform.output_map import OutputMapping, sweep_profile
from motionbase.platform.rrr3 import Rrr3
from motionbase.platform.rrr3_geometry import Rrr3Geometry
from motionbase.platform.rus6 import JacobianResult, JointPoints, Rus6
from motionbase.platform.rus6_geometry import Rus6Geometry
from motionbase.platform.rus6_workspace import (
    AxisReach,
    WorkspaceSlices,
    reachability_grid,
    single_axis_envelope,
    workspace_slices,
)
from motionbase.platform.stewart6 import Stewart6
from motionbase.platform.stewart6_geometry import Stewart6Geometry

__all__ = [
    "AxisReach",
    "CursorCalibration",
    "JacobianResult",
    "JointPoints",
    "OutputMapping",
    "Rrr3",
    "Rrr3Geometry",
    "Rus6",
    "Rus6Geometry",
    "Stewart6",
    "Stewart6Geometry",
    "WorkspaceSlices",
    "reachability_grid",
    "rotation_matrix",
    "single_axis_envelope",
    "sweep_profile",
    "workspace_slices",
]
