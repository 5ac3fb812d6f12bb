"""``motionbase replay`` against recordings that lie, change or hold odd values.

Found by an adversarial review of the replay path (crafted MCAP files, real CLI runs):
each test here failed on the code before its fix.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from mcap.writer import Writer

from motionbase import app, cli
from motionbase.errors import SourceError
from motionbase.io.mcap_source import RECORDED_STOP, McapSource, read_messages, read_metadata
from motionbase.io.pipeline_log import PipelineLog
from motionbase.pipeline import Pipeline, run
from motionbase.state import AircraftState
from motionbase.stopping import StopRequest

# --------------------------------------------------------------------------- --check's compare


KEYS = ("a", "b", "c", "d", "e", "f")


@pytest.mark.parametrize("where", range(len(KEYS)))
@pytest.mark.parametrize("recorded_nan", [True, False])
def test_check_sees_a_nan_against_a_number_wherever_it_sits(where, recorded_nan):
    """A value that is NaN on one side and a number on the other is a difference, wherever
    it sits in a message (a list position or a field). It was lost when ``max`` met it after
    a 0: ``max(0.0, nan)`` is 0.0, so the check said "identical"."""
    finite = [0.5 * k for k in range(len(KEYS))]
    with_nan = list(finite)
    with_nan[where] = math.nan
    rec, rep = (with_nan, finite) if recorded_nan else (finite, with_nan)
    as_list = app.compare_recordings({"/x": [{"v": rec}]}, {"/x": [{"v": rep}]})
    as_fields = app.compare_recordings(
        {"/x": [dict(zip(KEYS, rec, strict=True))]}, {"/x": [dict(zip(KEYS, rep, strict=True))]}
    )
    for report in (as_list, as_fields):
        assert not report.identical
        assert "check: DIFFERS" in report.lines()[0]


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_check_finds_the_same_non_finite_value_identical(value):
    """A replay that reproduces a non-finite value (a rejected NaN input, logged as it came)
    reproduces it bit for bit: no difference, whatever the order of the fields."""
    msg = {k: (value if k == "c" else 1.0) for k in KEYS}
    report = app.compare_recordings(
        {"/x": [msg, {"v": [value, 2.0]}]}, {"/x": [msg, {"v": [value, 2.0]}]}
    )
    assert report.identical, report.lines()


def test_check_of_an_integer_beyond_any_float_is_a_difference_not_a_crash():
    """JSON holds integers of any size (a crafted file); comparing one with a number raised
    OverflowError, a traceback from ``replay --check``."""
    report = app.compare_recordings({"/x": [{"n": 10**400}]}, {"/x": [{"n": 0}]})
    assert not report.identical
    assert app.compare_recordings({"/x": [{"n": 10**400}]}, {"/x": [{"n": 10**400}]}).identical


# --------------------------------------------------------------------------- a file that changes

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "recordings" / "c1723_30s.mcap"
ENV = {**os.environ, "PYTHONPATH": str(ROOT / "src")}


def test_a_recording_cut_while_it_is_read_is_a_source_error(tmp_path):
    """The states are counted when the source opens the file and read again while the
    pipeline runs; a file cut short in between (overwritten, truncated in place) used to end
    the replay there as if the recording ended there: exit 0, not a word."""
    rec = tmp_path / "rec.mcap"
    shutil.copyfile(SHIPPED, rec)
    with McapSource(rec) as source:
        whole = source.count
        with open(rec, "r+b") as fh:
            fh.truncate(rec.stat().st_size // 3)
        read = 0
        with pytest.raises(SourceError, match="changed while it was replayed") as caught:
            for _ in source:
                read += 1
    assert 0 < read < whole
    assert str(rec) in str(caught.value) and f"{read} of the {whole}" in str(caught.value)


def test_a_recording_cut_during_a_replay_parks_and_says_so_in_one_line(tmp_path):
    """The whole command, run in real time (``--live``: paced by the loop): the recording is
    emptied once the replay's log holds its first ticks. Exit 2, one line, and the log ends
    parked, at rest."""
    rec, out = tmp_path / "rec.mcap", tmp_path / "out.mcap"
    shutil.copyfile(SHIPPED, rec)
    proc = subprocess.Popen(
        [sys.executable, "-m", "motionbase", "replay", str(rec), "--live", "127.0.0.1:0",
         "--out", str(out)],
        env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        banner = proc.stderr.readline()
        assert banner.startswith("live view:"), banner
        # mid-run: once the log holds its first chunk (about a second of ticks)
        size = out.stat().st_size
        while out.stat().st_size == size and proc.poll() is None:
            time.sleep(0.05)
        with open(rec, "r+b") as fh:
            fh.truncate(0)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 2, stdout + stderr
    assert "Traceback" not in stderr
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, stderr
    assert str(rec) in lines[0] and "changed while it was replayed" in lines[0]
    assert "parked" in lines[0]
    # the log: from park back to park, at rest, within the geometry's limits
    geometry = read_metadata(out)["pipeline_config"]["geometry"]
    q = np.array([m["angles"] for m in read_messages(out)["/platform/actuators"]])
    rate = read_metadata(out)["pipeline_config"]["pipeline"]["rate_hz"]
    assert np.isfinite(q).all()
    assert len(q) > 120  # (it ran a while)
    assert np.allclose(q[-1], geometry["park_angle"], rtol=0, atol=1e-12)  # the park angle
    assert np.array_equal(q[-1], q[-2])  # at rest
    assert np.all(np.abs(np.diff(q, axis=0)) * rate <= np.asarray(geometry["max_speed"]) + 1e-9)


# --------------------------------------------------------------------------- crafted recordings


def _state(t: float) -> bytes:
    return json.dumps(
        {
            "t": t,
            "specific_force": [0.3 * math.sin(t), 0.2, -9.80665],
            "angular_velocity": [0.0, 0.05 * math.cos(t), 0.0],
            "attitude": [0.0, 0.02, 0.1],
        }
    ).encode()


def write_states(
    path: Path,
    n: int = 200,
    *,
    config: dict | str | None = None,
    ns_per_s: float = 1e9,
    payloads: list[bytes] | None = None,
) -> Path:
    """``n`` aircraft states at 100 Hz made with the mcap library (or the messages
    ``payloads``, 100 Hz apart); ``config`` as the motionbase metadata (a text as it is;
    none when None); log times ``ns_per_s`` units per second."""
    if payloads is None:
        payloads = [_state(k / 100) for k in range(n)]
    with open(path, "wb") as fh:
        writer = Writer(fh)
        writer.start()
        if config is not None:
            text = config if isinstance(config, str) else json.dumps(config)
            writer.add_metadata("motionbase", {"config": text})
        schema = writer.register_schema("state", "jsonschema", b"{}")
        channel = writer.register_channel("/aircraft/state", "json", schema)
        for k, data in enumerate(payloads):
            ns = round(k / 100 * ns_per_s)
            writer.add_message(channel, ns, data, ns)
        writer.finish()
    return path


def _states_and(path: Path, topic: str, encoding: str, payload: Callable[[int], bytes]) -> Path:
    """200 aircraft states at 100 Hz and, at each one's time, the message ``payload(k)`` on
    another ``topic`` (its ``encoding``), made with the mcap library."""
    with open(path, "wb") as fh:
        writer = Writer(fh)
        writer.start()
        states = writer.register_channel("/aircraft/state", "json", 0)
        other = writer.register_channel(topic, encoding, 0)
        for k in range(200):
            ns = round(k / 100 * 1e9)
            writer.add_message(states, ns, _state(k / 100), ns)
            writer.add_message(other, ns, payload(k), ns)
        writer.finish()
    return path


def _cli(capfd, *args) -> tuple[int, str, str]:
    code = cli.main([str(a) for a in args])
    captured = capfd.readouterr()
    return code, captured.out, captured.err


def _one_line(err: str) -> str:
    assert "Traceback" not in err, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    return lines[0]


@pytest.mark.parametrize(
    ("config", "ns_per_s", "said"),
    [
        (None, 1e6, "log times"),  # microseconds for nanoseconds: 100 kHz
        ({"rate_hz": 0.5}, 1e9, "rate_hz"),  # a configuration that lies
        ({"rate_hz": 50_000}, 1e9, "rate_hz"),
    ],
)
def test_a_recording_whose_rate_no_pipeline_runs_at_is_named(
    tmp_path, capfd, fresh_logger, config, ns_per_s, said
):
    """The rate a replay runs at comes from the recording (its configuration, else the
    spacing of its log times). One out of range used to be reported as if the user had
    given it ("pipeline: rate_hz 1e+05 is above 10 kHz (lower it)"): no file, no way to."""
    rec = write_states(tmp_path / "rec.mcap", config=config, ns_per_s=ns_per_s)
    code, out, err = _cli(capfd, "replay", rec, "--out", tmp_path / "out.mcap")
    assert code == 2
    line = _one_line(err)
    assert str(rec) in line and said in line
    assert not (tmp_path / "out.mcap").exists()  # refused before anything ran


# --------------------------------------------------------------------------- another robot

PLANAR = ROOT / "recordings" / "c1723_planar_15s.mcap"


@pytest.mark.parametrize("platform", ["ceart", "stewart6"])
def test_a_planar_recording_replays_on_the_6_dof_platform_it_is_given(
    tmp_path, capfd, fresh_logger, platform
):
    """``--platform`` overrides the recorded robot. A planar recording given a 6-DOF
    platform was refused with "--platform ceart: a preset of the 6-RUS, not a planar robot
    (drop --planar)": a flag nobody gave, and replay has none to turn planar mode off."""
    out = tmp_path / "out.mcap"
    code, stdout, err = _cli(capfd, "replay", PLANAR, "--platform", platform, "--out", out)
    assert code == 0, err
    assert "Traceback" not in err
    msgs = read_messages(out)
    assert "/planar/actuators" not in msgs
    angles = np.array([m["angles"] for m in msgs["/platform/actuators"]])
    assert angles.shape[1] == 6 and np.isfinite(angles).all()
    # every aircraft state of the recording went through
    assert len(msgs["/aircraft/state"]) == len(read_messages(PLANAR)["/aircraft/state"])


def test_another_platform_alone_keeps_the_recorded_washout(tmp_path, capfd, fresh_logger):
    """``--platform`` changes the robot and nothing else. A flight with ``--params gentle``
    replayed with ``--platform ceart`` (as ``replay --output`` needs, to drive motors) ran
    the platform's tuned default washout instead, which moves harder, without a word: its
    cue was not the recording's. On the recorded platform, it now is, tick for tick."""
    from motionbase.washout import WashoutParams

    rec, out = tmp_path / "gentle.mcap", tmp_path / "again.mcap"
    code, _, err = _cli(
        capfd, "fly", "c1723", "--params", "gentle", "--duration", "2", "--out", rec
    )
    assert code == 0, err
    code, _, err = _cli(capfd, "replay", rec, "--platform", "ceart", "--out", out)
    assert code == 0, err
    recorded = read_metadata(out)["pipeline_config"]["cueing_params"]
    assert WashoutParams.from_dict(recorded) == WashoutParams.preset("gentle")
    cue = [m["pose"] for m in read_messages(rec)["/washout/pose"]]
    assert cue == [m["pose"] for m in read_messages(out)["/washout/pose"]]
    # only the parameters are read: a recorded geometry that no longer loads (a rule
    # added since, say) does not stop a replay on the platform asked for
    meta = read_metadata(rec)
    meta["pipeline_config"]["geometry"]["crank"] = -1.0
    odd = write_states(tmp_path / "odd.mcap", config=meta)
    code, _, err = _cli(capfd, "replay", odd, "--platform", "ceart", "--out", out)
    assert code == 0, err
    recorded = read_metadata(out)["pipeline_config"]["cueing_params"]
    assert WashoutParams.from_dict(recorded) == WashoutParams.preset("gentle")
    # --params still changes them
    code, _, err = _cli(
        capfd, "replay", rec, "--platform", "ceart", "--params", "default", "--out", out
    )
    assert code == 0, err
    recorded = read_metadata(out)["pipeline_config"]["cueing_params"]
    assert WashoutParams.from_dict(recorded) == WashoutParams.preset("default")


def test_planar_is_still_refused_with_a_6_dof_platform_when_asked_for(
    tmp_path, capfd, fresh_logger
):
    code, _, err = _cli(capfd, "replay", PLANAR, "--planar", "--platform", "ceart")
    assert code == 2
    assert "drop --planar" in _one_line(err)


def test_a_recording_without_states_does_not_list_their_empty_topic_as_present(
    tmp_path, capfd, fresh_logger
):
    """A channel with no message on it is no topic present: the error said "no
    /aircraft/state messages in the recording (topics present: /aircraft/state)"."""
    rec = write_states(tmp_path / "rec.mcap", n=0, config={"rate_hz": 100.0})
    code, _, err = _cli(capfd, "replay", rec)
    assert code == 2
    line = _one_line(err)
    assert str(rec) in line and "no /aircraft/state messages" in line
    assert line.count("/aircraft/state") == 1 and "topics present: none" in line


@pytest.mark.parametrize("flag", ["--platform", "--params"])
def test_replay_out_may_not_overwrite_the_geometry_or_washout_file(
    tmp_path, capfd, fresh_logger, flag
):
    """``replay --out`` naming the ``--platform`` or ``--params`` file: the replay read it,
    then wrote its log over it. Only the recording itself was refused."""
    presets = ROOT / "src" / "motionbase" / "presets"
    source = presets / ("rus6_ceart.toml" if flag == "--platform" else "washout_gentle.toml")
    victim = tmp_path / "mine.toml"
    shutil.copyfile(source, victim)
    before = victim.read_bytes()
    code, _, err = _cli(
        capfd, "replay", SHIPPED, flag, victim, "--out", tmp_path / "." / "mine.toml"
    )
    assert code == 2
    line = _one_line(err)
    assert "--out" in line and flag in line and "destroy" in line
    assert victim.read_bytes() == before


# --------------------------------------------------------------------------- nesting


def test_a_state_nested_deeply_around_a_nan_string_is_rejected_not_a_traceback(
    tmp_path, capfd, fresh_logger
):
    """A message 900 lists deep holding ``"NaN"``: the parser reads it, then turning the
    string back into a number walked it recursively and raised RecursionError, a traceback
    from ``replay`` (and ``--check``, ``report``). Now it is a malformed state, rejected and
    held like any."""
    payloads = [_state(k / 100) for k in range(200)]
    payloads[50] = b"[" * 900 + b'"NaN"' + b"]" * 900
    rec = write_states(tmp_path / "rec.mcap", config={"rate_hz": 100.0}, payloads=payloads)
    out = tmp_path / "out.mcap"
    code, stdout, err = _cli(capfd, "replay", rec, "--out", out)
    assert code == 0, err
    assert "Traceback" not in err
    assert "1 malformed aircraft states rejected" in stdout
    assert read_messages(out)["/health"][-1]["rejected_inputs"] == 1


@pytest.mark.parametrize(
    "config", ["[" * 100_000 + "]" * 100_000, '{"a":' * 600 + '"NaN"' + "}" * 600]
)
def test_a_configuration_nested_too_deeply_is_one_line(tmp_path, capfd, fresh_logger, config):
    rec = write_states(tmp_path / "rec.mcap", 100, config=config)
    code, _, err = _cli(capfd, "replay", rec)
    assert code == 2
    line = _one_line(err)
    assert str(rec) in line and "metadata 'config'" in line


# --------------------------------------------------------------------------- a recorded stop


class _StoppedFlight:
    """Aircraft states at 120 Hz whose run is asked to stop (as a signal does) when state
    ``stop_at`` is handed over; the states go on, as a live source's do while it parks."""

    duration_s = None

    def __init__(self, stop: StopRequest, stop_at: int, estop_at: int | None = None) -> None:
        self.stop, self.stop_at, self.estop_at = stop, stop_at, estop_at

    def __iter__(self):
        for k in range(1, 3000):
            t = k / 120
            if k == self.stop_at:
                self.stop.set("SIGINT")
            if k == self.estop_at:
                self.stop.set("SIGINT while stopping", estop=True)
            yield AircraftState(
                t=t,
                specific_force=np.array([2.0 * math.sin(1.3 * t), math.cos(0.7 * t), -9.80665]),
                angular_velocity=np.array([0.1 * math.sin(t), 0.05, 0.0]),
                attitude=np.array([0.0, 0.02, 0.1]),
            )

    def describe(self) -> dict:
        return {"kind": "test"}


def _record_stopped_flight(path: Path, stop_at: int, estop_at: int | None = None) -> None:
    """A log of a run stopped at state ``stop_at`` (the pipeline's loop and log, as in
    ``fly`` and ``stream``)."""
    config = app.load_config()
    pipeline = Pipeline(config)
    stop = StopRequest()
    source = _StoppedFlight(stop, stop_at, estop_at)
    with PipelineLog(path, app.run_metadata(config, source), health=pipeline.health.as_dict,
                     robot=pipeline.robot, cueing=pipeline.cueing) as log:  # fmt: skip
        summary = run(pipeline, source, [log], stop=stop)
    assert summary.stopped_by.startswith("SIGINT") and pipeline.parked


def test_a_recording_of_a_stopped_run_replays_bit_for_bit(tmp_path):
    """A run stopped by Ctrl-C (how every ``stream`` ends) parks while its source goes on;
    the replay fed the same states to a pipeline that never stopped, then parked after the
    last: ``replay --check`` said DIFFERS for every such recording. Now the replay stops at
    the state where the recording's poses start stopping."""
    rec = tmp_path / "stopped.mcap"
    _record_stopped_flight(rec, stop_at=700)
    recorded = read_messages(rec)
    stopping = [m["phase"] for m in recorded["/platform/pose"]].index("stopping")
    assert recorded["/aircraft/state"][stopping]["t"] == recorded["/platform/pose"][stopping]["t"]
    assert len(recorded["/aircraft/state"]) > stopping + 100  # states went on while it parked

    result = app.replay(rec, check=True, progress=False)
    assert not result.failed, "\n".join(result.notes)
    assert "check: identical to the recording" in result.notes
    assert result.summary.stopped_by == RECORDED_STOP


def test_a_recorded_e_stop_is_not_reproduced_and_the_check_says_so(tmp_path):
    """An E-stop is not in the log tick by tick (only /health counts it, once a second):
    the replay reproduces the stop before it, and the check's difference is explained."""
    rec = tmp_path / "estopped.mcap"
    _record_stopped_flight(rec, stop_at=700, estop_at=760)
    result = app.replay(rec, check=True, progress=False)
    assert result.failed
    assert any("E-stop" in line for line in result.notes), result.notes


def test_a_user_stop_during_a_replay_still_leaves_the_check_unmade(tmp_path):
    stop = StopRequest()
    stop.set("SIGTERM")
    result = app.replay(SHIPPED, check=True, progress=False, stop=stop)
    assert result.failed
    assert "check: not made, the replay was stopped (SIGTERM)" in result.notes


def test_a_flight_stopped_by_ctrl_c_replays_bit_for_bit(tmp_path):
    """The same through the commands: ``fly --realtime`` stopped by a real SIGINT once its
    log holds its first ticks, then ``replay --check`` of its log."""
    out = tmp_path / "fly.mcap"
    proc = subprocess.Popen(
        [sys.executable, "-m", "motionbase", "fly", "c1723", "--realtime", "--out", str(out)],
        env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        for _ in range(12000):  # the log's first chunk: about a second of flight
            if (out.exists() and out.stat().st_size > 20_000) or proc.poll() is not None:
                break
            time.sleep(0.01)
        assert proc.poll() is None, proc.communicate()
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 0 and "stopped by SIGINT" in stdout, stdout + stderr
    check = subprocess.run(
        [sys.executable, "-m", "motionbase", "replay", str(out), "--check"],
        env=ENV, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert check.returncode == 0, check.stdout + check.stderr
    assert "check: identical to the recording" in check.stdout


def test_a_check_whose_log_was_removed_says_so_and_exits_1(tmp_path):
    """The replay's log removed during a ``--check`` run: the run warned that the log is
    gone, then the check tried to read it and failed with "file not found (check the
    path)", exit status 2, as if the user had given a wrong path."""
    rec = write_states(tmp_path / "rec.mcap", n=300, config={"rate_hz": 100.0})
    folder = tmp_path / "logs"
    folder.mkdir()
    out = folder / "out.mcap"
    proc = subprocess.Popen(
        [sys.executable, "-m", "motionbase", "replay", str(rec), "--check", "--live",
         "127.0.0.1:0", "--out", str(out)],
        env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        banner = proc.stderr.readline()
        assert banner.startswith("live view:"), banner
        shutil.rmtree(folder)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 1, stdout + stderr
    assert "Traceback" not in stderr and "error" not in stderr, stderr
    assert "is gone" in stderr
    assert "check: not made, the replay's log is gone" in stdout


# --------------------------------------------------------------------------- --preview as recorded


def test_the_command_replays_a_preview_recording_with_its_preview(tmp_path, capfd, fresh_logger):
    """``app.replay`` previews as the recording was made unless told; the command passed
    ``--preview``'s default, False, so ``motionbase replay REC --check`` of any recording
    made with ``fly --preview`` said DIFFERS (the MPC planned on the current sample only)."""
    rec = tmp_path / "preview.mcap"
    app.fly("c1723", cueing="mpc", preview=True, duration_s=2.0, out=rec, progress=False)
    assert read_metadata(rec).get("preview") is True
    code, stdout, err = _cli(capfd, "replay", rec, "--check")
    assert code == 0, stdout + err
    assert "check: identical to the recording" in stdout


def test_a_recording_that_claims_a_preview_its_cueing_cannot_use_is_named(
    tmp_path, capfd, fresh_logger
):
    rec = tmp_path / "claims.mcap"
    stored = read_metadata(SHIPPED)["pipeline_config"]
    assert stored["cueing"] == "classical"
    write_states(rec, config={"pipeline_config": stored, "preview": True})
    code, _, err = _cli(capfd, "replay", rec)
    assert code == 2
    line = _one_line(err)
    assert str(rec) in line and "preview" in line and "metadata" in line


# --------------------------------------------------------------------------- duplicated samples


@pytest.mark.parametrize("copies", [1, 3])
def test_a_state_sent_twice_costs_one_rejection_not_the_rest_of_the_recording(
    tmp_path, capfd, fresh_logger, copies
):
    """A state recorded again right after itself (a sender that repeats, a merge): the copy
    did not advance time and was rejected, the rejected tick moved the clock on by one
    period, and from then on every new state tied with that clock and was rejected too:
    146 of the 240 states after one copy, and a watchdog fade to neutral. Now only the
    copies are rejected."""
    payloads = [_state(k / 100) for k in range(1, 301)]
    payloads[60:60] = [payloads[59]] * copies  # state 60 again, right after itself
    rec = write_states(tmp_path / "rec.mcap", config={"rate_hz": 100.0}, payloads=payloads)
    out = tmp_path / "out.mcap"
    code, _, err = _cli(capfd, "replay", rec, "--out", out)
    assert code == 0, err
    log = read_messages(out)
    health = log["/health"][-1]
    assert health["rejected_inputs"] == copies
    assert health["watchdog_fades"] == 0
    accepted = [m["accepted"] for m in log["/aircraft/state"]]
    assert accepted.count(False) == copies
    assert not any(accepted[60 : 60 + copies]) and all(accepted[60 + copies :])
    # the tick times still increase
    times = [m["t"] for m in log["/platform/pose"]]
    assert all(b > a for a, b in zip(times, times[1:], strict=False))


def test_a_check_of_an_older_recording_with_a_tf_message_that_is_no_object_says_differs(
    tmp_path, capfd, fresh_logger
):
    """An older log's /tf (log format "1", or a file that does not say) is shifted to the
    platform's origin before the compare; a /tf message that is not a JSON object (a list)
    ended ``replay --check`` in an AttributeError traceback."""
    rec = _states_and(
        tmp_path / "rec.mcap",
        "/tf",
        "json",
        lambda k: b"[1, 2]" if k == 7 else b'{"child_frame_id": "x"}',
    )
    code, out, err = _cli(capfd, "replay", rec, "--check")
    assert code == 1 and "Traceback" not in err, err
    assert "check: DIFFERS" in out and "DIFF /tf" in out


@pytest.mark.parametrize("usable_at", [None, 150])
def test_a_recording_without_a_usable_state_is_refused_before_anything_moves(
    tmp_path, capfd, fresh_logger, usable_at
):
    """Every aircraft state malformed or not finite: nothing to replay. The replay ran
    anyway (exit 0, a warning): the platform went through its start and park with no cue,
    and a --check compared nothing of use. One usable state is enough to replay."""
    nan = {
        "specific_force": [math.nan, 0, -9.8],
        "angular_velocity": [0, 0, 0],
        "attitude": [0] * 3,
    }
    payloads = [
        b'{"t": 0.5, "specific_force": "abc"}'
        if k % 2
        else json.dumps({"t": k / 100, **nan}).encode()
        for k in range(200)
    ]
    if usable_at is not None:
        payloads[usable_at] = _state(usable_at / 100)
    rec = write_states(tmp_path / "rec.mcap", payloads=payloads, config={"rate_hz": 100.0})
    out = tmp_path / "out.mcap"
    code, stdout, err = _cli(capfd, "replay", rec, "--out", out)
    if usable_at is not None:
        assert code == 0, err
        assert "100 malformed aircraft states" in stdout and "rejected inputs 199;" in stdout
        return
    assert code == 2
    line = _one_line(err)
    assert str(rec) in line and "none of its 200 aircraft states can be used" in line
    assert "message 1: a number in it is not finite" in line and "a state needs a time t" in line
    assert not out.exists()


@pytest.mark.parametrize("limits", [None, {"max_specific_force": 2e4}])
@pytest.mark.parametrize("first_malformed", [False, True])
def test_a_recording_whose_every_state_is_absurd_is_refused_unless_its_limits_allow_them(
    tmp_path, capfd, fresh_logger, limits, first_malformed
):
    """Every state finite but beyond the input limits (another tool's file in other units:
    a specific force in cm/s^2, 1000 of them): the pipeline rejects each one, and the replay
    ran its start and park with no cue, exit 0, as for malformed states. With the limits
    recorded for the run that allow them, it replays them, also when the first state is
    malformed (the refusal went by the first state's reason alone and refused them)."""
    payloads = [
        json.dumps({"t": k / 100, "specific_force": [0.0, 0.0, -981.0],
                    "angular_velocity": [0.0] * 3, "attitude": [0.0] * 3}).encode()
        for k in range(200)
    ]  # fmt: skip
    if first_malformed:
        payloads[0] = b"[]"
    config: dict = {"rate_hz": 100.0}
    if limits is not None:
        recorded = app.load_config(rate_hz=100.0).to_dict()
        recorded["pipeline"]["input_limits"] = limits
        config["pipeline_config"] = recorded
    rec = write_states(tmp_path / "rec.mcap", payloads=payloads, config=config)
    out = tmp_path / "out.mcap"
    code, stdout, err = _cli(capfd, "replay", rec, "--out", out)
    if limits is not None:
        assert code == 0 and f"rejected inputs {int(first_malformed)};" in stdout, err
        return
    assert code == 2 and not out.exists()
    line = _one_line(err)
    assert "none of its 200 aircraft states can be used" in line, line
    why = (
        "the message is [], not a JSON object"
        if first_malformed
        else "specific force beyond its bound"
    )
    assert f"message 1: {why}" in line, line


@pytest.mark.parametrize(
    ("limit", "force"),
    [(5.0, 9.80665), (2e4, 1e5)],  # tighter than the default 150 m/s^2; wider, not enough
)
def test_a_recording_whose_every_state_is_beyond_its_recorded_limits_is_refused(
    tmp_path, capfd, fresh_logger, limit, force
):
    """The refusal of a recording without a usable state goes by the limits the run has,
    the recorded ones: states within the default limits but beyond tighter recorded ones,
    or beyond both the default and wider recorded ones, were each rejected by the run,
    which ran its start and park with no cue, exit 0 (the scan judged them by the default
    limits alone)."""
    payloads = [
        json.dumps({"t": k / 100, "specific_force": [0.0, 0.0, -force],
                    "angular_velocity": [0.0] * 3, "attitude": [0.0] * 3}).encode()
        for k in range(200)
    ]  # fmt: skip
    recorded = app.load_config(rate_hz=100.0).to_dict()
    recorded["pipeline"]["input_limits"] = {"max_specific_force": limit}
    config = {"rate_hz": 100.0, "pipeline_config": recorded}
    rec = write_states(tmp_path / "rec.mcap", payloads=payloads, config=config)
    out = tmp_path / "out.mcap"
    code, _, err = _cli(capfd, "replay", rec, "--out", out)
    assert code == 2 and not out.exists(), err
    line = _one_line(err)
    assert "none of its 200 aircraft states can be used" in line, line
    assert "message 1: specific force beyond its bound" in line, line


def test_a_check_it_cannot_make_is_refused_before_the_replay_runs(tmp_path, capfd, fresh_logger):
    """A recording with a topic that is not JSON (a camera merged in) cannot be compared:
    ``replay --check`` ran the whole replay first (motors too, with --output), then said so
    and exited 2."""
    rec = _states_and(tmp_path / "merged.mcap", "/camera", "protobuf", lambda k: b"\x0a\x04jpeg")
    out = tmp_path / "out.mcap"
    code, stdout, err = _cli(capfd, "replay", rec, "--check", "--out", out)
    assert code == 2
    assert "'/camera' is 'protobuf'-encoded" in _one_line(err)
    assert not out.exists() and "replayed" not in stdout  # nothing ran


def test_a_preview_replay_of_a_cut_recording_warns_once(tmp_path, capfd, fresh_logger):
    """``replay --preview`` read the recording twice, each time with its warnings: a cut
    recording was said to be truncated twice, and its first malformed state malformed twice."""
    rec = tmp_path / "cut.mcap"
    with open(rec, "wb") as fh:
        writer = Writer(fh, chunk_size=4096)  # many chunks: the cut leaves most of them
        writer.start()
        channel = writer.register_channel("/aircraft/state", "json", 0)
        for k in range(300):
            ns = round(k / 100 * 1e9)
            writer.add_message(channel, ns, b"[]" if k == 50 else _state(k / 100), ns)
        writer.finish()
    rec.write_bytes(rec.read_bytes()[: rec.stat().st_size * 2 // 3])
    out = tmp_path / "out.mcap"
    code, stdout, err = _cli(capfd, "replay", rec, "--cueing", "mpc", "--preview", "--out", out)
    assert code == 0 and "Traceback" not in err, err
    assert "preview: the mpc cueing saw the flight's future" in stdout
    assert err.count("is truncated") == 1 and err.count("is malformed") == 1, err
    assert "1 malformed aircraft states rejected" in stdout
    assert [m["accepted"] for m in read_messages(out)["/aircraft/state"]].count(False) == 1


def test_a_check_of_a_newer_log_format_is_refused_before_the_replay_runs(
    tmp_path, capfd, fresh_logger
):
    """A recording whose metadata says a log format this version does not write (made by a
    newer motionbase) cannot be compared message for message: ``replay --check`` says so,
    and which version made it, in one line before anything moves (it compared the layouts
    anyway and said DIFFERS, which reads as a fault of the replay). Its format may hold
    topics this version cannot read (here one not JSON): the format is named, not them."""
    from mcap.reader import make_reader

    made = tmp_path / "made.mcap"
    assert cli.main(["fly", "c1723", "--duration", "1", "--out", str(made)]) == 0
    capfd.readouterr()
    rec = tmp_path / "newer.mcap"
    with open(made, "rb") as src, open(rec, "wb") as fh:
        reader = make_reader(src)
        writer = Writer(fh)
        writer.start()
        for meta in reader.iter_metadata():
            writer.add_metadata(meta.name, {**meta.metadata, "log_format": "9", "version": "9.0"})
        ids: dict[int, int] = {}
        for schema, channel, message in reader.iter_messages():
            if channel.id not in ids:
                sid = (
                    writer.register_schema(schema.name, schema.encoding, schema.data)
                    if schema
                    else 0
                )
                ids[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, sid
                )
            writer.add_message(
                ids[channel.id], message.log_time, message.data, message.publish_time
            )
        writer.add_message(writer.register_channel("/camera", "cbor", 0), 1, b"\xa0", 1)
        writer.finish()
    out = tmp_path / "out.mcap"
    code, stdout, err = _cli(capfd, "replay", rec, "--check", "--out", out)
    assert code == 2
    line = _one_line(err)
    assert "log format '9' (motionbase 9.0)" in line and "cannot check it" in line, line
    assert not out.exists() and "replayed" not in stdout  # nothing ran
    # the replay itself (no check) still runs: the state messages are as this version reads them
    assert _cli(capfd, "replay", rec, "--out", out)[0] == 0
