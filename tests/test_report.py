"""``motionbase report``: plots, summary and cueing metrics of real (short) JSBSim recordings."""

from __future__ import annotations

import logging
import math
import re

import numpy as np
import pytest
from matplotlib.image import imread
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation

from motionbase.app import fly
from motionbase.cli import main
from motionbase.errors import LogFormatError
from motionbase.io.mcap_log import McapLogger
from motionbase.io.mcap_source import read_messages, read_metadata
from motionbase.io.report_plots import default_report_dir, report_figures, write_report
from motionbase.pipeline import PipelineConfig
from motionbase.report import build_report

G = 9.80665
PNGS = (
    "specific_force.png",
    "angular_velocity.png",
    "perceived.png",
    "pose.png",
    "actuators.png",
    "timeline.png",
)
AIRCRAFT_RGB = (0x1F, 0x4E, 0x9C)  # the report's aircraft colour
CUE_RGB = (0xD9, 0x48, 0x0F)  # the report's platform colour


@pytest.fixture(scope="module")
def rus6_run(tmp_path_factory):
    """The flight's :class:`~motionbase.app.RunResult` and its log."""
    path = tmp_path_factory.mktemp("rus6") / "c1723.mcap"
    # the SIMONA set (gains 0.5), which the last test tells from a perfect cueing
    return fly("c1723", duration_s=10, out=path, washout="default", progress=False), path


@pytest.fixture(scope="module")
def rus6_flight(rus6_run):
    return rus6_run[1]


@pytest.fixture(scope="module")
def planar_flight(tmp_path_factory):
    path = tmp_path_factory.mktemp("planar") / "c1723_planar.mcap"
    fly("c1723", planar=True, duration_s=10, out=path, progress=False)
    return path


@pytest.fixture(scope="module")
def rus6_written(rus6_flight):
    """The report written through the CLI with the default output folder."""
    assert main(["report", str(rus6_flight)]) == 0
    return default_report_dir(rus6_flight)


@pytest.fixture(scope="module")
def planar_written(planar_flight, tmp_path_factory):
    out = tmp_path_factory.mktemp("planar_report") / "rep"
    files = write_report(planar_flight, out)
    assert files.out_dir == out
    return out


def _colour_pixels(img: np.ndarray, rgb: tuple[int, int, int], tol: float = 0.06) -> int:
    target = np.array(rgb) / 255.0
    return int((np.abs(img[..., :3] - target) < tol).all(axis=-1).sum())


def _check_images(folder):
    for name in PNGS:
        img = imread(folder / name)  # raises on a broken PNG
        h, w = img.shape[:2]
        assert h >= 300 and w >= 600, (name, img.shape)
        rgb = np.round(img[..., :3] * 255).astype(np.int32)
        packed = (rgb[..., 0] << 16 | rgb[..., 1] << 8 | rgb[..., 2]).ravel()
        assert not (packed == packed[0]).all(), f"{name}: blank image"
        assert np.unique(packed).size > 50, f"{name}: almost no content"
        # the drawn series: the platform colour is on every plot, the aircraft colour on the
        # comparisons
        assert _colour_pixels(img, CUE_RGB) > 300, f"{name}: no platform curve"
        if name in PNGS[:3]:
            assert _colour_pixels(img, AIRCRAFT_RGB) > 300, f"{name}: no aircraft curve"


def test_rus6_pngs_are_real_images(rus6_written, rus6_flight):
    assert rus6_written == rus6_flight.parent / "c1723_report"
    _check_images(rus6_written)


def test_planar_pngs_are_real_images(planar_written):
    _check_images(planar_written)


def _row(text: str, label: str) -> list[str]:
    line = next(ln for ln in text.splitlines() if ln.strip().startswith(label))
    return line[len(line) - len(line.lstrip()) + len(label) :].split()


METRIC_ROWS = (
    "specific force RMSE [m/s^2]",
    "specific force correlation",
    "specific force false cues [%]",
    "angular velocity RMSE [deg/s]",
    "angular velocity correlation",
    "angular velocity false cues [%]",
    "workspace usage [% of reach]",
)


def test_rus6_summary_names_every_metric_with_finite_numbers(rus6_written):
    text = (rus6_written / "summary.txt").read_text()
    for label in METRIC_ROWS:
        cells = _row(text, label)
        n = 6 if label.startswith("workspace") else 3
        assert len(cells) == n, (label, cells)
        values = [float(c) for c in cells]  # "n/a" would fail here
        assert all(math.isfinite(v) for v in values), (label, values)
        if "correlation" in label:
            assert all(-1.0 <= v <= 1.0 for v in values)
        if "false cues" in label or "workspace" in label:
            assert all(0.0 <= v for v in values)
        if "false cues" in label:
            assert all(v <= 100.0 for v in values)
    # crank range within the recorded limits (+-60 deg for ceart)
    for line in text.splitlines():
        m = re.match(r"\s+(\d): +(-?[\d.]+) \.\. +(-?[\d.]+) +\((-?[\d.]+) \.\. (-?[\d.]+)\)", line)
        if m:
            lo, hi, lim_lo, lim_hi = map(float, m.groups()[1:])
            assert lim_lo <= lo <= hi <= lim_hi


def test_range_used_is_the_flights_as_the_end_of_run_summary_says(rus6_run, rus6_written):
    """The crank ranges are the flight's (full motion), the start and park ramps on a line of
    their own, as the end-of-run summary gives them: they took every tick, so each range ran
    from the park angle (-55 deg), 5 deg from the -60 deg limit, whatever the flight did."""
    result, path = rus6_run
    msgs = read_messages(path)
    phase = {m["t"]: m["phase"] for m in msgs["/platform/pose"]}
    angles = np.degrees([m["angles"] for m in msgs["/platform/actuators"]])
    flight = np.array([phase[m["t"]] == "running" for m in msgs["/platform/actuators"]])
    expected = np.array([angles[flight].min(axis=0), angles[flight].max(axis=0)])
    assert (angles[~flight].min(axis=0) < expected[0] - 1.0).all()  # the park angle lies below
    text = (rus6_written / "summary.txt").read_text()
    used = []
    for line in text.splitlines():
        m = re.match(r"\s+(\d): +(-?[\d.]+) \.\. +(-?[\d.]+) +\(", line)
        if m:
            used.append([float(m[2]), float(m[3])])
    assert len(used) == 6
    np.testing.assert_allclose(np.transpose(used), expected, rtol=0, atol=0.051)
    np.testing.assert_allclose(np.transpose(used), np.degrees(result.summary.angle_range),
                               rtol=0, atol=0.051)  # fmt: skip
    assert f"flight ({int(flight.sum())} ticks at full motion)" in text
    s = result.summary
    assert f"parking: start ramp {s.start_s:.1f} s, way back to park {s.stop_s:.1f} s" in text


def test_planar_summary_says_what_the_robot_cannot_cue(planar_written):
    text = (planar_written / "summary.txt").read_text()
    assert "planar" in text and "cannot tilt" in text
    # the 3-RRR has no heave, roll or pitch: those comparisons are undefined, not zero
    assert _row(text, "specific force correlation")[2] == "n/a"
    roll, pitch, yaw = _row(text, "angular velocity correlation")
    assert roll == "n/a" and pitch == "n/a" and math.isfinite(float(yaw))
    usage = _row(text, "workspace usage [% of reach]")
    assert usage[2:5] == ["n/a", "n/a", "n/a"]
    assert all(math.isfinite(float(u)) for u in usage[:2] + usage[5:])
    x, y, _ = _row(text, "specific force RMSE [m/s^2]")
    assert math.isfinite(float(x)) and math.isfinite(float(y))


def test_tilt_coordination_cue_follows_the_sustained_forward_force(rus6_flight):
    """c1723 accelerates steadily from about 3.5 s: the platform must pitch nose up and the
    pilot feel a forward force of about the washout gain times the aircraft's, from tilt."""
    msgs = read_messages(rus6_flight)
    meta = read_metadata(rus6_flight)
    r = build_report(msgs, meta)
    seg = (r.t >= 6.0) & (r.t <= 9.5)
    f_air = r.aircraft_f[seg, 0]
    assert f_air.min() > 1.0  # the aircraft's sustained forward force, independent of us
    pitch = r.cab_pose[seg, 4]
    assert (pitch > np.radians(2.0)).all()  # nose up (FRD: positive pitch)
    cue = r.cue_f[seg, 0]
    assert (cue > 0).all()
    # sustained: the translation has washed out, the force is gravity's share through the tilt
    assert np.abs(cue - G * np.sin(pitch)).max() < 0.1
    gain = meta["pipeline_config"]["cueing_params"]["scaling"]["specific_force_gain"][0]
    ratio = cue.mean() / f_air.mean()
    assert abs(ratio - gain) < 0.25 * gain, (ratio, gain)


def _reproduce_platform(msgs):
    """The aircraft replaced by exactly what the recorded platform pose makes the pilot feel,
    computed another way: spline accelerations and scipy rotations."""
    poses = msgs["/platform/pose"]
    t = np.array([p["t"] for p in poses])
    pose = np.array([p["pose"] for p in poses])
    acc = CubicSpline(t, pose[:, :3])(t, 2)
    rot = Rotation.from_euler("ZYX", pose[:, [5, 4, 3]])  # R = Rz Ry Rx, platform -> base
    f = np.einsum("nji,nj->ni", rot.as_matrix(), acc - np.array([0.0, 0.0, G]))
    w = np.zeros_like(f)  # body rates from relative rotations over two steps
    w[1:-1] = (rot[:-2].inv() * rot[2:]).as_rotvec() / (t[2:] - t[:-2])[:, None]
    w[0], w[-1] = w[1], w[-2]
    index = {x: i for i, x in enumerate(t)}
    air = []
    for m in msgs["/aircraft/state"]:
        i = index[m["t"]]
        air.append({**m, "specific_force": f[i].tolist(), "angular_velocity": w[i].tolist()})
    return {**msgs, "/aircraft/state": air}


def test_exact_reproduction_scores_near_perfect(rus6_flight):
    msgs = read_messages(rus6_flight)
    meta = read_metadata(rus6_flight)
    real = build_report(msgs, meta).metrics
    rep = build_report(_reproduce_platform(msgs), meta)
    perfect = rep.metrics
    # the plotted cue is the reproduced motion, sample by sample, while running
    run = rep.running
    np.testing.assert_allclose(rep.cue_f[run], rep.aircraft_f[run], atol=0.05)
    np.testing.assert_allclose(rep.cue_w[run], rep.aircraft_w[run], atol=np.radians(0.2))
    assert (perfect.correlation_specific_force > 0.98).all(), perfect.correlation_specific_force
    assert (perfect.correlation_angular_velocity > 0.98).all(), perfect.correlation_angular_velocity
    assert (perfect.rmse_specific_force < 0.05).all()  # m/s^2, well under the 0.17 threshold
    assert (np.degrees(perfect.rmse_angular_velocity) < 0.1).all()
    assert (perfect.false_cue_angular_velocity == 0).all()
    # the false-cue count has no margin at the threshold: allow the few samples where the two
    # derivative methods straddle it
    assert (perfect.false_cue_specific_force < 0.05).all()
    # and the metric tells real washout cueing (gain 0.5, washed out) from a perfect one
    assert (perfect.rmse_specific_force[:2] < 0.1 * real.rmse_specific_force[:2]).all()
    # the platform pose is the same: so is its workspace usage
    np.testing.assert_array_equal(perfect.workspace_usage, real.workspace_usage)


def test_not_mcap_is_a_one_line_error(tmp_path, capsys):
    bad = tmp_path / "notes.mcap"
    bad.write_text("hello, not a recording\n")
    assert main(["report", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "not an MCAP file" in err and str(bad) in err


def test_recording_without_aircraft_state_is_a_one_line_error(tmp_path, capsys):
    path = tmp_path / "empty.mcap"
    with McapLogger(path, {"note": "no aircraft"}) as log:
        for k in range(5):
            log.add("/washout/pose", k / 120, {"pose": [0.0] * 6})
    with pytest.raises(LogFormatError, match="/aircraft/state"):
        write_report(path, tmp_path / "out")
    assert main(["report", str(path), "--out", str(tmp_path / "out2")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "/aircraft/state" in err
    assert not (tmp_path / "out2").exists()


# --------------------------------------------------------------------------- what the plots draw


def _axis(fig, ylabel_start: str):
    """The subplot whose y label starts with ``ylabel_start``."""
    found = [ax for ax in fig.axes if ax.get_ylabel().startswith(ylabel_start)]
    assert len(found) == 1, [ax.get_ylabel() for ax in fig.axes]
    return found[0]


def _line(ax, label_start: str):
    found = [ln for ln in ax.get_lines() if ln.get_label().startswith(label_start)]
    assert len(found) == 1, [ln.get_label() for ln in ax.get_lines()]
    return np.asarray(found[0].get_xdata(), float), np.asarray(found[0].get_ydata(), float)


def _texts(fig) -> list[str]:
    texts = [fig.get_suptitle()] if hasattr(fig, "get_suptitle") else []
    texts += [t.get_text() for t in fig.texts]
    for ax in fig.axes:
        texts += [ax.get_title(), ax.get_xlabel(), ax.get_ylabel()]
    return texts


def test_rus6_pose_plot_shows_heave_up(rus6_flight):
    msgs = read_messages(rus6_flight)
    fig = report_figures(build_report(msgs, read_metadata(rus6_flight)))["pose.png"]
    ax = _axis(fig, "heave up")
    assert ax.get_ylabel() == "heave up [cm]"
    t, up_cm = _line(ax, "realised")
    poses = msgs["/platform/pose"]
    np.testing.assert_array_equal(t, [p["t"] for p in poses])
    # FRD: the logged z is down; the plot shows up, in cm
    np.testing.assert_allclose(up_cm, [-100.0 * p["pose"][2] for p in poses], rtol=1e-12)
    # the physics, independent of the sign convention: parked, every crank points down
    # (negative angle: its tip below the pivot), so the seat is below neutral
    parked = np.array([m["angles"] for m in msgs["/platform/actuators"]])[-1]
    assert (parked < np.radians(-30)).all()
    assert up_cm[-1] < -5.0 and up_cm[0] < -5.0
    _, washout_cm = _line(ax, "washout")
    np.testing.assert_allclose(washout_cm, [-100.0 * m["pose"][2] for m in msgs["/washout/pose"]])
    # the reach lines are drawn the same way up: the recorded platform's heave reach, found
    # here by a plain scan of its inverse kinematics within the crank limits (0.1 mm steps),
    # up (negative z) drawn positive; the larger reach is upward
    robot = PipelineConfig.from_dict(read_metadata(rus6_flight)["pipeline_config"]).make_robot()
    lo, hi = robot.limits.lower, robot.limits.upper
    z = np.arange(-0.5, 0.5, 1e-4)
    poses = np.zeros((z.size, 6))
    poses[:, 2] = z
    q = robot.inverse(poses)
    ok = np.isfinite(q).all(axis=1) & (q >= lo).all(axis=1) & (q <= hi).all(axis=1)
    centre = np.argmin(np.abs(z))
    assert ok[centre] and not ok[0] and not ok[-1]
    top = z[centre - np.argmin(ok[centre::-1])]  # the first pose up that is out of reach
    bottom = z[centre + np.argmin(ok[centre:])]  # and down
    reach = sorted(ln.get_ydata()[0] for ln in ax.get_lines() if ln.get_linestyle() == ":")
    assert reach[0] == pytest.approx(-100.0 * bottom, abs=0.011)
    assert reach[1] == pytest.approx(-100.0 * top, abs=0.011)
    assert reach[1] > -reach[0] > 0.0
    # other axes keep the logged sign and say which way is positive
    assert _axis(fig, "pitch").get_ylabel() == "pitch (nose up) [deg]"
    assert _axis(fig, "surge").get_ylabel() == "surge (forward) [cm]"


def test_perceived_plot_is_labelled_in_the_units_it_draws(rus6_flight):
    r = build_report(read_messages(rus6_flight), read_metadata(rus6_flight))
    fig = report_figures(r)["perceived.png"]
    texts = _texts(fig)
    assert not any("normalis" in s.lower() or "normaliz" in s.lower() for s in texts), texts
    for axis in ("x", "y", "z"):
        ax = _axis(fig, f"otolith {axis}")
        assert ax.get_ylabel() == f"otolith {axis} [m/s²]"
        # the drawn data are the perceived specific forces in m/s^2
        _, air = _line(ax, "aircraft")
        col = "xyz".index(axis)
        np.testing.assert_array_equal(air, r.perceived.aircraft_specific_force[:, col])
    # c1723's sustained forward acceleration (> 1 m/s^2 from 6 s, see above) reads as such
    _, air_x = _line(_axis(fig, "otolith x"), "aircraft")
    assert air_x.max() > 1.0


def test_planar_pose_plot_draws_the_realised_pose_through_the_stop(planar_flight):
    from motionbase.platform import Rrr3, Rrr3Geometry

    msgs = read_messages(planar_flight)
    meta = read_metadata(planar_flight)
    fig = report_figures(build_report(msgs, meta))["pose.png"]
    poses = msgs["/planar/pose"]
    phases = [p["phase"] for p in poses]
    assert "stopping" in phases and phases[-1] == "parked"
    # the mapping back to a cab, computed here from the recorded configuration
    config = meta["pipeline_config"]
    home = Rrr3(Rrr3Geometry.from_dict(config["geometry"])).home
    scale = config["pipeline"]["planar_scale_m"]
    # surge is robot x, sway robot -y (the plane is z up, the cab's axes FRD)
    xy = (np.array([p["pose"][:2] for p in poses]) - home[:2]) / [scale, -scale]
    t_all = np.array([p["t"] for p in poses])
    for name, col in (("surge", 0), ("sway", 1)):
        t, cm = _line(_axis(fig, name), "realised")
        np.testing.assert_array_equal(t, t_all)  # every tick, the stop phase included
        np.testing.assert_allclose(cm, 100.0 * xy[:, col], atol=1e-9)


def test_a_recording_cut_before_any_state_is_one_line_without_a_warning(
    rus6_flight, tmp_path, capsys, monkeypatch
):
    """Cut to 10 bytes (or before the first chunk), a file gave a 'truncated' WARNING line
    and then the error; nothing usable was read, so the error alone is said."""
    log = logging.getLogger("motionbase")  # cli.main puts its handler on this test's stderr
    monkeypatch.setattr(log, "handlers", [])
    monkeypatch.setattr(log, "propagate", True)
    data = rus6_flight.read_bytes()
    for size in (10, 200):
        cut = tmp_path / f"cut{size}.mcap"
        cut.write_bytes(data[:size])
        assert main(["report", str(cut), "--out", str(tmp_path / "rep")]) == 2
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and "WARNING" not in err, err
        assert str(cut) in err and "no /aircraft/state messages" in err and "cut short" in err
        assert not (tmp_path / "rep").exists()
    # with states before the cut, they are read, and the warning says so
    cut = tmp_path / "half.mcap"
    cut.write_bytes(data[: len(data) // 2])
    messages = read_messages(cut, require="/aircraft/state")
    assert messages["/aircraft/state"]
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "WARNING" in err and "truncated" in err, err


def test_a_recording_cut_anywhere_after_its_first_states_gives_a_report(rus6_flight, tmp_path):
    """A killed run's file can end between a tick's aircraft state and its pose (every
    message of a tick is written together, but a cut falls anywhere): the report leaves the
    last states without a pose out. It used to fail on most cuts ("1 /aircraft/state
    messages have no /platform/pose at the same time")."""
    data = rus6_flight.read_bytes()
    messages = read_messages(rus6_flight)
    whole_ticks = len(messages["/platform/pose"])
    reported = 0
    for share in np.linspace(0.3, 0.95, 14):
        cut = tmp_path / f"cut{share:.3f}.mcap"
        cut.write_bytes(data[: int(share * len(data))])
        got = read_messages(cut)
        if not got.get("/aircraft/state"):
            continue  # cut before the first chunk of states: the one-line error above
        report = build_report(got, read_metadata(cut), name=cut.name)
        n_air = len(got["/aircraft/state"])
        poses = {float(m["t"]) for m in got["/platform/pose"]}
        kept = sum(float(m["t"]) in poses for m in got["/aircraft/state"])
        assert report.t.size == kept and kept >= n_air - 1 and kept <= whole_ticks
        assert np.isfinite(report.metrics.rmse_specific_force).all()
        reported += 1
    assert reported >= 10


def test_the_planar_robot_is_named_without_a_stray_comma(planar_written):
    """The summary's first line and the plots' titles name the robot from its description
    ("3-RRR, planar mode"): the first word kept the comma, "(planar 3-RRR,, source ...)"."""
    first = (planar_written / "summary.txt").read_text().splitlines()[0]
    assert "(planar 3-RRR, source " in first and ",," not in first, first


def test_the_summary_says_when_an_mpcs_solver_failed(tmp_path):
    """A recording of an MPC flight whose solver failed (one iteration never solves) has
    each tick's fallback on /cueing/mpc; the report scored the fallback washout's cue as
    the MPC's without a word. Its summary now says on how many ticks the solver failed; a
    recording without such ticks says nothing of it."""
    import dataclasses

    from motionbase.io.manoeuvres import write_washout
    from motionbase.washout.mpc_params import MpcParams

    failing = tmp_path / "failing.toml"
    params = dataclasses.replace(MpcParams.load("tuned_ceart"), max_iter=1)
    write_washout(failing, params, ["never solved"])
    out = tmp_path / "mpc.mcap"
    fly("c1723", cueing="mpc", washout=str(failing), duration_s=2.5, out=out, progress=False)
    text = write_report(out, tmp_path / "rep").out_dir.joinpath("summary.txt").read_text()
    (line,) = [x for x in text.splitlines() if "fell back" in x]
    failed, ticks = map(int, re.search(r"failed on (\d+) of (\d+) ticks", line).groups())
    assert ticks == len(read_messages(out)["/cueing/mpc"]) and failed > ticks // 2, line
    solved = tmp_path / "solved.mcap"
    fly("c1723", cueing="mpc", duration_s=2.5, out=solved, progress=False)
    text = write_report(solved, tmp_path / "rep2").out_dir.joinpath("summary.txt").read_text()
    assert "fell back" not in text


def test_the_planar_reach_ends_where_the_robot_does_not_where_the_scan_did():
    """The planar report's single-axis reach scanned only 0.2 m and 0.2 rad from home and
    gave the scan's end as the reach: yaw +-22.9 deg of cab (0.2 rad of the robot / 0.5),
    when the 3-RRR turns its platform to +45 deg and more at home. Each bound must be a true
    edge: every pose from home to it reachable, the pose just past it not."""
    from motionbase.platform import Rrr3
    from motionbase.platform.rrr3_geometry import Rrr3Geometry
    from motionbase.report import planar_reach

    geometry = Rrr3Geometry.preset("udesc_symmetric")
    kin = Rrr3(geometry)
    home = np.asarray(kin.home, dtype=float)
    scale_m, yaw_scale = 0.1, 0.5
    reach = planar_reach(geometry, scale_m, yaw_scale)
    assert np.isnan(reach[:, 2:5]).all()  # no heave, roll or pitch
    # the robot at home turns its platform to +45 deg and to -15 deg: counter-clockwise seen
    # from above (the plane is z up), a yaw to the left of the cab (FRD: negative yaw)
    for phi in (math.radians(45.0), math.radians(-15.0)):
        assert kin.reachable(home + [0.0, 0.0, phi])
    assert reach[0, 5] * yaw_scale < -math.radians(45.0)
    # robot x is surge, robot y the cab's left (-sway), phi the cab's -yaw
    for col, j, scale in ((0, 0, scale_m), (1, 1, -scale_m), (5, 2, -yaw_scale)):
        for row in (0, 1):
            edge = reach[row, col] * scale  # robot units, signed
            assert edge != 0.0
            path = np.tile(home, (2001, 1))
            path[:, j] += np.linspace(0.0, edge * (1 - 1e-6), 2001)
            assert kin.reachable(path).all(), (col, row)
            beyond = home.copy()
            beyond[j] += edge + math.copysign(1e-5, edge)
            assert not kin.reachable(beyond), (col, row, edge)


def test_an_empty_out_is_refused_not_the_current_folder(rus6_flight, tmp_path, monkeypatch, capsys):
    """``--out ""`` (an unset ``$DIR``) wrote the six plots and summary.txt into the current
    folder, over any files of those names there; omct refuses it, and so does report now."""
    monkeypatch.chdir(tmp_path)
    mine = tmp_path / "summary.txt"
    mine.write_text("my own notes\n")
    assert main(["report", str(rus6_flight), "--out", ""]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "--out: empty" in err, err
    assert mine.read_text() == "my own notes\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["summary.txt"]


def test_the_report_leaves_the_robots_drawing_unread(rus6_flight):
    """The report decoded every topic, /platform/scene included (the robot drawn for
    Foxglove, about 75 kB a message once decoded, 30 a second: 8 GB for an hour's
    stream), which it never uses. What it reads must take a fraction of the memory of
    every message, and give the same report."""
    import tracemalloc

    from motionbase.io.report_plots import read_recording

    def traced(read):
        tracemalloc.start()
        try:
            result = read()
            return result, tracemalloc.get_traced_memory()[0]
        finally:
            tracemalloc.stop()

    everything, full = traced(lambda: read_messages(rus6_flight))
    assert len(everything["/platform/scene"]) > 100
    (messages, metadata), used = traced(lambda: read_recording(rus6_flight))
    assert "/platform/scene" not in messages and "/tf" not in messages
    assert used < 0.3 * full, (used, full)
    fewer = build_report(messages, metadata, name="r")
    whole = build_report(everything, read_metadata(rus6_flight), name="r")
    assert fewer.text == whole.text


def _with(msgs, topic, k, change):
    """``msgs`` with message ``k`` on ``topic`` replaced by ``change(message)``."""
    changed = [*msgs.get(topic, [])]
    changed[k] = change(changed[k])
    return {**msgs, topic: changed}


def _without(key):
    return lambda m: {f: v for f, v in m.items() if f != key}


@pytest.mark.parametrize(
    ("topic", "change", "said"),
    [
        ("/washout/pose", _without("t"), "/washout/pose: a message has no numeric 't'"),
        ("/washout/pose", lambda m: {**m, "t": "soon"}, "/washout/pose: a message has no numeric"),
        ("/washout/pose", lambda m: [1, 2], "/washout/pose: message 51 is [1, 2], not a JSON"),
        ("/platform/actuators", lambda m: "x", "/platform/actuators: message 51 is 'x', not a"),
        ("/platform/pose", lambda m: None, "/platform/pose: message 51 is None, not a JSON obj"),
        ("/platform/pose", lambda m: {**m, "fade": "abc"}, "field 'fade' holds 'abc', not a nu"),
        ("/aircraft/state", lambda m: {**m, "t": 10**400}, "/aircraft/state: a message has no"),
    ],
)
def test_a_message_of_the_wrong_shape_is_a_one_line_error_not_a_traceback(
    rus6_flight, topic, change, said
):
    """Messages a report reads that are not JSON objects, or hold a field it cannot read,
    ended ``report`` in a KeyError, TypeError, ValueError or OverflowError traceback."""
    msgs = read_messages(rus6_flight, skip={"/platform/scene"})
    with pytest.raises(LogFormatError, match=re.escape(said)) as err:
        build_report(_with(msgs, topic, 50, change), read_metadata(rus6_flight), name="r.mcap")
    assert str(err.value).startswith("r.mcap: ") and "\n" not in str(err.value)


def test_odd_values_a_report_can_do_without_leave_a_report(rus6_flight):
    """A fade of null, a number beyond any float and a /cueing/ topic of strings do not stop a
    report (each was a traceback): the null is no fade, the huge number a rejected sample
    held like a NaN, the strings no solver's messages."""
    msgs = read_messages(rus6_flight, skip={"/platform/scene"})
    meta = read_metadata(rus6_flight)
    whole = build_report(msgs, meta)
    k = int(np.flatnonzero(whole.running)[10])  # an aircraft sample while running
    msgs = _with(msgs, "/platform/pose", 50, lambda m: {**m, "fade": None})
    msgs = _with(msgs, "/aircraft/state", k, lambda m: {**m, "specific_force": [10**400, 0, 0]})
    msgs = {**msgs, "/cueing/mpc": ["fallback", "fallback"]}
    rep = build_report(msgs, meta)
    assert np.isnan(rep.fade[50]) and (rep.fade[:50] == 1.0).all()
    assert np.flatnonzero(rep.rejected).tolist() == [k] and not whole.rejected.any()
    np.testing.assert_array_equal(rep.aircraft_f[k], rep.aircraft_f[k - 1])  # held
    assert rep.cueing_fallbacks is None


def test_a_recording_merged_with_a_camera_is_reported(rus6_flight, tmp_path, capsys):
    """A recording merged with another tool's protobuf topic (a camera, to view both in
    Foxglove) is reported, the camera left out with a warning; it was refused whole."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    merged = tmp_path / "merged.mcap"
    with open(rus6_flight, "rb") as src, open(merged, "wb") as fh:
        reader, writer = make_reader(src), Writer(fh)
        writer.start()
        for meta in reader.iter_metadata():
            writer.add_metadata(meta.name, meta.metadata)
        camera = writer.register_channel("/camera", "protobuf", 0)
        ids: dict[int, int] = {}
        for schema, channel, msg in reader.iter_messages(log_time_order=False):
            if channel.id not in ids:
                sid = writer.register_schema(schema.name, schema.encoding, schema.data)
                ids[channel.id] = writer.register_channel(channel.topic, "json", sid)
            writer.add_message(ids[channel.id], msg.log_time, msg.data, msg.publish_time)
            writer.add_message(camera, msg.log_time, b"\x0a\x04jpeg", msg.log_time)
        writer.finish()
    assert main(["report", str(merged), "--out", str(tmp_path / "rep")]) == 0
    err = capsys.readouterr().err
    assert "Traceback" not in err and "/camera: 'protobuf'-encoded" in err
    assert (tmp_path / "rep" / "summary.txt").read_text() == build_report(
        read_messages(rus6_flight), read_metadata(rus6_flight), name="merged.mcap"
    ).text


@pytest.mark.parametrize("source", ["jsbsim", [1, 2], None])
def test_a_recorded_source_that_is_no_table_is_an_unknown_source(rus6_flight, source):
    """The metadata's ``source`` that is not a JSON object (a string, a list) ended the
    report in an AttributeError traceback; the pipeline configuration is all it needs."""
    meta = {**read_metadata(rus6_flight), "source": source}
    text = build_report(read_messages(rus6_flight, skip={"/platform/scene"}), meta).text
    assert text.startswith("motionbase report: recording (6-RUS, source unknown source, ")


def _refused_ticks(msgs, geometry: dict) -> int:
    """Ticks whose logged planar pose and servo angles put a chain within its type I margin
    or the platform within the type II margin, from the thesis's geometry (appendix A.1)
    and the log alone: sin(crank, rod) from the crank tips and platform joints, and
    |det Jx| / (b^3 h / sqrt(3)); every chain closed (the rod's length) checked first."""
    L, a, b, h = (geometry[k] for k in ("base_side", "crank", "rod", "platform_side"))
    base = np.array([[0.0, 0.0], [L, 0.0], [L / 2, L * math.sqrt(3) / 2]])
    x, y, phi = np.array([m["pose"] for m in msgs["/planar/pose"]]).T
    th = np.array([m["angles"] for m in msgs["/planar/actuators"]])
    r = h / math.sqrt(3)
    c1 = np.stack([x - r * np.cos(math.pi / 6 + phi), y - r * np.sin(math.pi / 6 + phi)], -1)
    c = np.stack(
        [c1, c1 + h * np.stack([np.cos(phi), np.sin(phi)], -1)]
        + [c1 + h * np.stack([np.cos(phi + math.pi / 3), np.sin(phi + math.pi / 3)], -1)],
        1,
    )
    tips = base + a * np.stack([np.cos(th), np.sin(th)], -1)
    crank, rod = tips - base, c - tips
    np.testing.assert_allclose(np.linalg.norm(rod, axis=-1), b, atol=1e-9)  # closed
    type1 = np.abs(crank[..., 0] * rod[..., 1] - crank[..., 1] * rod[..., 0]) / (a * b)
    e = c - np.stack([x, y], -1)[:, None]
    jx = np.stack([rod[..., 0], rod[..., 1], e[..., 0] * rod[..., 1] - e[..., 1] * rod[..., 0]], -1)
    type2 = np.abs(np.linalg.det(jx)) / (b**3 * h / math.sqrt(3))
    safety = geometry["safety"]
    return int(((type1 < safety["type1_margin"]).any(1) | (type2 < safety["type2_margin"])).sum())


def test_the_planar_report_says_when_the_limiter_left_the_valid_poses(
    tmp_path, planar_flight, monkeypatch
):
    """The Concorde's take-off run drives the 3-RRR's cue into its workspace's edge at speed:
    near a chain's type I singularity its servo must turn ever faster; limited each alone
    (the robot's coordinated limit off, as before it), that servo lags, then overshoots the
    clamped pose, and chain 2 went through its singularity (its working mode flipped) for
    tens of ticks. The report put the over-100 % surge down to "combining axes" and said
    nothing else. It counts those ticks, as the log's own geometry does; the coordinated
    limit (the default) and a gentle flight have none."""
    from motionbase.platform.rrr3 import Rrr3Robot

    def flown(name: str):
        out = tmp_path / f"{name}.mcap"
        fly("Concorde_runway_test", planar=True, out=out, progress=False)
        msgs = read_messages(out)
        return (
            msgs,
            read_metadata(out),
            _refused_ticks(msgs, read_metadata(out)["pipeline_config"]["geometry"]),
        )

    with monkeypatch.context() as m:
        m.setattr(Rrr3Robot, "coordinated", False)
        msgs, meta, expected = flown("per_servo")
    assert expected > 0
    text = " ".join(build_report(msgs, meta).text.split())
    found = re.search(r"warning: (\d+) ticks \([\d.]+ %\) realised poses the robot's", text)
    assert found and int(found.group(1)) == expected, text
    assert "past the valid poses" in text
    msgs, meta, expected = flown("coordinated")
    assert expected == 0 and "warning" not in build_report(msgs, meta).text
    gentle = read_messages(planar_flight)
    assert _refused_ticks(gentle, read_metadata(planar_flight)["pipeline_config"]["geometry"]) == 0
    assert "warning" not in build_report(gentle, read_metadata(planar_flight)).text
