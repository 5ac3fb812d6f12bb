"""JsbsimSource: physics at the edge, rates, quietness, no files in the cwd, realtime pacing."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from motionbase.app import load_config
from motionbase.errors import ConfigError, SourceError
from motionbase.io.base import Source
from motionbase.io.jsbsim_source import JsbsimSource, available_scripts
from motionbase.pipeline import Pipeline, run
from motionbase.stopping import StopRequest

G = 9.80665


@pytest.fixture(scope="module")
def c1723_5s():
    with JsbsimSource("c1723", duration_s=5.0) as src:
        return src, list(src)


def test_is_a_source_at_the_script_rate(c1723_5s) -> None:
    src, states = c1723_5s
    assert isinstance(src, Source)
    assert src.rate_hz == pytest.approx(120.0)
    assert src.duration_s == 5.0
    assert len(states) == 600
    t = np.array([s.t for s in states])
    assert np.allclose(np.diff(t), 1 / 120, atol=1e-9)
    assert t[0] == pytest.approx(1 / 120) and t[-1] == pytest.approx(5.0)
    assert all(s.is_finite() and s.angular_acceleration is not None for s in states)


def test_specific_force_is_gravity_in_body_axes_while_parked(c1723_5s) -> None:
    """Brakes on for the first 3 s: f = R^T (0, 0, -g) from the attitude, in m/s^2."""
    _, states = c1723_5s
    parked = [s for s in states if 0.5 <= s.t <= 2.9]
    for s in parked:
        roll, pitch, _ = s.attitude
        expected = -G * np.array(
            [-np.sin(pitch), np.sin(roll) * np.cos(pitch), np.cos(roll) * np.cos(pitch)]
        )
        # the engine spools up against the brakes: allow a few tenths of a m/s^2
        assert np.allclose(s.specific_force, expected, atol=0.35)
        assert s.specific_force[2] == pytest.approx(-G, rel=0.03)
        assert np.all(np.abs(s.angular_velocity) < 0.1)


def test_climb_specific_force_is_about_one_g(tmp_path: Path) -> None:
    """In the autopilot climb the mean specific force is close to 1 g, mostly along -z."""
    with JsbsimSource("c1723", duration_s=60.0) as src:
        states = [s for s in src if s.t >= 40.0]
    f = np.array([s.specific_force for s in states])
    assert np.linalg.norm(f, axis=1).mean() == pytest.approx(G, rel=0.1)
    assert f[:, 2].mean() < -0.85 * G


def test_decimated_samples_equal_the_full_rate_ones() -> None:
    with JsbsimSource("c1723", duration_s=2.0) as full_src:
        full = list(full_src)
    with JsbsimSource("c1723", duration_s=2.0, rate_hz=40.0) as dec_src:
        dec = list(dec_src)
    assert dec_src.rate_hz == 40.0 and len(dec) == 80
    for a, b in zip(full[2::3], dec, strict=True):
        assert a.t == b.t
        assert np.array_equal(a.specific_force, b.specific_force)
        assert np.array_equal(a.attitude, b.attitude)


def test_quiet_and_leaves_the_working_directory_alone(tmp_path: Path, monkeypatch, capfd):
    """The whole c1723 run: no banner or notices, and its state file goes to a temp folder."""
    monkeypatch.chdir(tmp_path)
    seen_files: list[str] = []
    with JsbsimSource("c1723") as src:
        out_dir = src.output_dir
        assert out_dir is not None and out_dir.is_dir()
        n = 0
        for _ in src:
            n += 1
        seen_files = sorted(p.name for p in out_dir.iterdir())
    assert n == 24000
    # c1723 writes a state file once above 1000 ft: it went to the temporary folder ...
    assert any(name.startswith("initfile") for name in seen_files)
    # ... which is gone, and nothing reached the working directory or the terminal
    assert not out_dir.exists()
    assert list(tmp_path.iterdir()) == []
    out, err = capfd.readouterr()
    assert out == "" and err == ""


def test_bad_script_name_says_how_to_find_names(tmp_path: Path) -> None:
    with pytest.raises(SourceError) as err:
        JsbsimSource("c17233")
    msg = str(err.value)
    assert "c1723" in msg and "available_scripts" in msg and "\n" not in msg
    assert "c1723" in available_scripts()
    with pytest.raises(SourceError, match="not found") as err:
        JsbsimSource("/no/such/script.xml")
    assert "without .xml" not in str(err.value)
    # a shipped script's file name, not in the current folder: its name is the one to give
    with pytest.raises(SourceError, match=r"named c1723, without \.xml"):
        JsbsimSource("c1723.xml")
    folder = tmp_path / "scripts.xml"
    folder.mkdir()
    with pytest.raises(SourceError, match="a folder, not a JSBSim script"):
        JsbsimSource(str(folder))


def test_bad_rate_and_duration_are_config_errors() -> None:
    with pytest.raises(ConfigError, match="120/n"):
        JsbsimSource("c1723", rate_hz=100.0)
    with pytest.raises(ConfigError, match="duration_s"):
        JsbsimSource("c1723", duration_s=-1.0)


def _script(tmp_path: Path, run: str) -> Path:
    path = tmp_path / "timing.xml"
    path.write_text(
        '<?xml version="1.0"?>\n<runscript name="timing">'
        '<use aircraft="c172x" initialize="reset00"/>'
        f"<run {run}></run></runscript>\n"
    )
    return path


@pytest.mark.parametrize("duration_s", [None, 3.0])
def test_a_script_without_an_end_time_is_refused_saying_what_to_add(tmp_path, duration_s):
    """JSBSim will not load a script whose <run> has no end, whatever the duration: the
    error said "give duration_s" (a --duration then failed in JSBSim's loader), or, with
    one, came from JSBSim only once the source opened."""
    path = _script(tmp_path, 'start="0" dt="0.008333"')
    with pytest.raises(SourceError) as err:
        JsbsimSource(str(path), duration_s=duration_s)
    assert str(path) in str(err.value) and 'end="' in str(err.value)


@pytest.mark.parametrize("run", ['start="10" end="5"', 'start="5" end="5"'])
def test_a_script_that_ends_before_it_starts_is_refused(tmp_path, run):
    """<run end> not after <run start>: the source yielded no state at all, and fly parked
    at once and exited 0 as if the script had been flown."""
    path = _script(tmp_path, f'{run} dt="0.008333"')
    with pytest.raises(SourceError) as err:
        JsbsimSource(str(path))
    assert str(path) in str(err.value) and "not after its start" in str(err.value)


def test_script_by_path_and_describe(tmp_path: Path) -> None:
    src = JsbsimSource("c1723")
    path = src.describe()["path"]
    by_path = JsbsimSource(path, duration_s=0.5)
    desc = by_path.describe()
    assert desc["kind"] == "jsbsim" and desc["jsbsim_version"]
    assert desc["rate_hz"] == 120.0 and desc["duration_s"] == 0.5
    assert json.dumps(desc)
    assert len(list(by_path)) == 60  # iterating opens and closes the source itself


def test_says_when_its_duration_cut_the_script_short(tmp_path: Path) -> None:
    """``ended`` (what the run's summary says stopped it): "duration" when ``duration_s``
    ends the flight before the script does, nothing when the script's own end does."""
    cut = JsbsimSource("c1723", duration_s=0.5)
    assert cut.ended == "" and len(list(cut)) == 60 and cut.ended == "duration"
    script = Path(JsbsimSource("c1723").describe()["path"]).read_text()
    short = re.sub(r'(<run[^>]*\bend=")[^"]*"', r'\g<1>0.5"', script, count=1)
    assert short != script
    (tmp_path / "short.xml").write_text(short)
    whole = JsbsimSource(str(tmp_path / "short.xml"), duration_s=10.0)  # longer than it
    assert whole.duration_s == 0.5 and len(list(whole)) == 60 and whole.ended == ""
    with JsbsimSource("c1723", duration_s=0.5) as source:
        summary = run(Pipeline(load_config(rate_hz=source.rate_hz)), source)
    assert summary.stopped_by == "duration"
    # a stop in full motion, 0.5 s before the duration runs out: the way back to park (2 s)
    # outlasts the flight, whose end then comes; the stop is what stopped the run
    stop = StopRequest()

    def ask_at_2_5_s(out) -> None:
        if out.t >= 2.5 and out.phase == "running":
            stop.set("test")

    with JsbsimSource("c1723", duration_s=3.0) as source:
        pipeline = Pipeline(load_config(rate_hz=source.rate_hz))
        summary = run(pipeline, source, stop=stop, progress=ask_at_2_5_s)
    assert source.ended == "duration"  # (the flight did end meanwhile)
    assert summary.stopped_by == "test" and pipeline.parked


def test_from_aircraft_applies_initial_conditions(capfd) -> None:
    init = {
        "ic/h-sl-ft": 3000.0,
        "ic/vc-kts": 100.0,
        "ic/psi-true-deg": 90.0,
        "ic/theta-deg": 0.0,
        "ic/phi-deg": 0.0,
    }
    src = JsbsimSource.from_aircraft("c172x", init, rate_hz=60.0, duration_s=1.0)
    states = list(src)
    assert src.rate_hz == 60.0 and len(states) == 60
    assert np.allclose(np.diff([s.t for s in states]), 1 / 60, atol=1e-9)
    assert states[0].attitude[2] == pytest.approx(np.pi / 2, abs=0.05)
    assert abs(states[0].attitude[0]) < 0.05
    out, err = capfd.readouterr()
    assert out == "" and err == ""
    with pytest.raises(SourceError, match="aircraft"):
        JsbsimSource.from_aircraft("c172xx", init)
