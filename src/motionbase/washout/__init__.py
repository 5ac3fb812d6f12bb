"""Motion cueing: the classical washout filter (Reid & Nahon) and perception models."""

from motionbase.washout.classical import ClassicalWashout, WashoutInputError, WashoutState
from motionbase.washout.params import WashoutParams
from motionbase.washout.perception import (
    CueingMetrics,
    PerceivedMotion,
    cueing_metrics,
    perceived_motion,
    platform_angular_velocity,
    platform_specific_force,
)

__all__ = [
    "ClassicalWashout",
    "CueingMetrics",
    "PerceivedMotion",
    "WashoutInputError",
    "WashoutParams",
    "WashoutState",
    "cueing_metrics",
    "perceived_motion",
    "platform_angular_velocity",
    "platform_specific_force",
]
