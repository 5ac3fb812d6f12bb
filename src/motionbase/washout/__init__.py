"""Motion cueing: the classical washout filter (Reid & Nahon)."""

from motionbase.washout.classical import ClassicalWashout, WashoutInputError, WashoutState
from motionbase.washout.params import WashoutParams

__all__ = ["ClassicalWashout", "WashoutInputError", "WashoutParams", "WashoutState"]
