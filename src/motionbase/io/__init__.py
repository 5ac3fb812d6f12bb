"""The edges: every adapter that touches JSBSim, sockets, files or serial ports.

Each source yields :class:`~motionbase.state.AircraftState` samples in SI units
and FRD body axes; each sink takes pipeline outputs. Both are context managers
(``with source: for state in source: ...``). See :mod:`motionbase.io.base`.
"""
