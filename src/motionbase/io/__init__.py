"""The edges: every adapter that touches JSBSim, sockets, files or serial ports.

Each source yields :class:`~motionbase.state.AircraftState` samples in SI units
and FRD body axes; each sink takes pipeline outputs. Both are context managers
(``with source: for state in source: ...``). See :mod:`motionbase.io.base`.
"""

# --- MCAP and JSBSim (issue 4) ---
from motionbase.io.jsbsim_source import JsbsimSource, available_scripts  # noqa: E402, F401
from motionbase.io.mcap_log import McapLogger  # noqa: E402, F401
from motionbase.io.mcap_source import McapSource, read_messages, read_metadata  # noqa: E402, F401
from motionbase.io.schemas import TOPIC_SCHEMAS  # noqa: E402, F401

# --- MAVLink (issue 6) ---
# isort: split
from motionbase.io.mavlink_source import (  # noqa: E402, F401
    MavlinkSource,
    MavlinkStats,
    MavlinkTick,
    load_signing_key,
)

# --- motor-drive output (issue 8) ---
# isort: split
from motionbase.io.motor_output import (  # noqa: E402, F401
    BinaryFormat,
    MotorOutput,
    TextFormat,
    open_output,
    open_outputs,
    parse_format,
)
