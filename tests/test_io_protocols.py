"""Every real source and sink is what io/base.py says it is (the types run() takes)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from motionbase import pipeline, state
from motionbase.io.base import (
    EndingSource,
    LiveSource,
    SelfPacedSource,
    Sink,
    Source,
    StaleMarkingSource,
)

RECORDING = Path(__file__).parents[1] / "recordings" / "c1723_30s.mcap"


def _sources():
    from motionbase.io.fgnative_source import FgNativeSource
    from motionbase.io.jsbsim_source import JsbsimSource
    from motionbase.io.mavlink_source import MavlinkSource
    from motionbase.io.mcap_source import McapSource
    from motionbase.io.xplane_source import XPlaneSource

    return {
        # name: (make one, marks stale holds, paces itself, says why it ended)
        "jsbsim": (lambda: JsbsimSource("c1723"), False, False, True),  # the loop paces it
        "mcap": (lambda: McapSource(RECORDING), True, False, False),  # (no --duration)
        "mavlink": (lambda: MavlinkSource("udpin:127.0.0.1:0"), True, True, True),
        "flightgear": (lambda: FgNativeSource("fgnative:udp:127.0.0.1:0"), True, True, True),
        "xplane": (lambda: XPlaneSource("xplane:127.0.0.1:49000"), True, True, True),
    }


@pytest.mark.parametrize("name", ["jsbsim", "mcap", "mavlink", "flightgear", "xplane"])
def test_every_source_is_a_source_with_its_capabilities(name: str) -> None:
    make, stale, paced, ending = _sources()[name]
    src = make()
    assert isinstance(src, Source)
    assert isinstance(src, EndingSource) == ending
    assert isinstance(src, StaleMarkingSource) == stale
    assert isinstance(src, SelfPacedSource) == paced
    assert isinstance(src, LiveSource) == (stale and paced)


def test_every_sink_is_a_sink(tmp_path: Path) -> None:
    from motionbase.app import PlanarServoOutput
    from motionbase.io.motor_output import open_output
    from motionbase.io.pipeline_log import PipelineLog
    from motionbase.io.serial_link import ServoSerialSink
    from motionbase.platform.output_map import OutputMapping

    mapping = OutputMapping.default(np.full(6, -1.0), np.full(6, 1.0))
    sinks = [
        PipelineLog(tmp_path / "run.mcap", {"rate_hz": 120.0}),
        open_output("udp:127.0.0.1:9", mapping),
        ServoSerialSink("loop://"),
        PlanarServoOutput("loop://"),
    ]
    for sink in sinks:
        assert isinstance(sink, Sink), type(sink).__name__
    assert not isinstance(object(), Sink)
    assert not isinstance([1.0], Source)  # an iterable alone is not a source (run takes both)


def test_the_records_crossing_the_boundary_live_in_state() -> None:
    """The sinks name PipelineOutput without importing the pipeline; the pipeline re-exports it."""
    assert pipeline.PipelineOutput is state.PipelineOutput
    assert state.PipelineOutput.__module__ == "motionbase.state"
