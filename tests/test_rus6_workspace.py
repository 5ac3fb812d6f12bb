"""6-RUS workspace: single-axis envelope against a scan of the inverse kinematics, grids,
slices, CLI, plot."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from motionbase.cli import main
from motionbase.io.workspace_plots import plot_rus6_workspace
from motionbase.platform import Rus6, Rus6Geometry
from motionbase.platform.rus6_workspace import (
    AXES,
    format_envelope,
    reachability_grid,
    single_axis_envelope,
    workspace_slices,
)

RUS6 = Rus6(Rus6Geometry.preset("ceart"))
ENVELOPE = single_axis_envelope(RUS6)
SCAN_STEP = 1e-4  # m or rad


def scanned_reach(robot: Rus6, axis: int, sign: float) -> tuple[float, float]:
    """The reach along one axis found another way: a plain scan from neutral in steps of
    :data:`SCAN_STEP` of the inverse kinematics (checked against a root finder on the leg
    closures in test_rus6) and the crank limits, not of ``reachable``. Returns the last
    value whose pose closes every leg within the limits and the first that does not."""
    limit = 2.0 if axis < 3 else math.pi
    s = np.arange(0.0, limit + SCAN_STEP, SCAN_STEP)
    poses = np.zeros((s.size, 6))
    poses[:, axis] = sign * s
    q = robot.inverse(poses)
    lo, hi = robot.angle_limits
    ok = np.isfinite(q).all(axis=1) & (q >= lo).all(axis=1) & (q <= hi).all(axis=1)
    assert ok[0] and not ok.all(), AXES[axis]
    first_bad = int(np.argmin(ok))
    return float(s[first_bad - 1]), float(s[first_bad])


@pytest.mark.parametrize("axis", AXES)
def test_envelope_is_where_a_scan_of_the_inverse_kinematics_first_leaves_the_limits(axis):
    """Both directions of each axis, to the scan's step (it compared with the README's
    rounded figures, themselves printed by this code, within 3 %)."""
    assert [a.axis for a in ENVELOPE] == list(AXES)
    j = AXES.index(axis)
    for sign, reach in ((-1.0, ENVELOPE[j].negative), (1.0, ENVELOPE[j].positive)):
        last_ok, first_bad = scanned_reach(RUS6, j, sign)
        assert last_ok - 1e-9 <= reach <= first_bad, (axis, sign, reach, last_ok)


def test_envelope_is_mirror_symmetric_left_to_right():
    # a seat simulator is symmetric about its x-z plane: sway, roll and yaw reach the same
    # both ways (to the sweep's tolerance); pitch serves forward acceleration (nose up) more
    reach = {a.axis: a for a in ENVELOPE}
    for axis in ("sway", "roll", "yaw"):
        assert reach[axis].negative == pytest.approx(reach[axis].positive, rel=1e-5), axis
    assert reach["pitch"].positive > 1.5 * reach["pitch"].negative
    assert reach["surge"].positive > reach["surge"].negative


def test_geometry_mirrors_onto_itself():
    # mirroring the neutral platform in y (y -> -y) maps the set of legs onto itself: pivots,
    # crank tips and joints of leg i land on those of one other leg
    jp = RUS6.joint_points(np.zeros(6))
    mirror = np.array([1.0, -1.0, 1.0])
    for points in (jp.pivots, jp.crank_tips, jp.platform_joints):
        m = points * mirror
        d = np.linalg.norm(m[:, None, :] - points[None, :, :], axis=-1)
        partner = d.argmin(axis=1)
        assert d.min(axis=1).max() < 1e-12
        assert sorted(partner) == list(range(6))
    # a mirrored pose (sway, roll, yaw negated) needs the mirrored legs' crank angles
    pose = np.array([0.05, 0.08, -0.03, 0.1, -0.05, 0.2])
    mirrored = pose * np.array([1, -1, 1, -1, 1, -1])
    partner = np.linalg.norm(
        (jp.pivots * mirror)[:, None, :] - jp.pivots[None, :, :], axis=-1
    ).argmin(axis=1)
    np.testing.assert_allclose(RUS6.inverse(mirrored)[partner], RUS6.inverse(pose), atol=1e-12)


@pytest.mark.parametrize("j", range(6))
def test_envelope_edges_are_where_a_crank_hits_its_limit(j):
    lo, hi = RUS6.angle_limits
    for sign, value in ((-1, ENVELOPE[j].negative), (1, ENVELOPE[j].positive)):
        inside = np.zeros(6)
        inside[j] = sign * value
        outside = inside.copy()
        outside[j] = sign * (value + 1e-6)
        assert RUS6.reachable(inside)
        assert not RUS6.reachable(outside)
        # for ceart every single-axis edge is a crank limit (DESIGN: "crank limits only")
        angles = RUS6.inverse(inside)
        assert np.min(np.abs(np.r_[angles - lo, hi - angles])) < 1e-6


def test_reachability_grid_matches_pointwise_checks():
    x = np.linspace(-0.4, 0.4, 9)
    y = np.linspace(-0.4, 0.4, 7)
    z = np.linspace(-0.25, 0.15, 5)
    orientation = (0.05, -0.1, 0.2)
    grid = reachability_grid(RUS6, x, y, z, orientation)
    assert grid.shape == (9, 7, 5) and grid.dtype == bool
    for i, j, k in [(4, 3, 3), (0, 0, 0), (8, 6, 4), (2, 5, 1), (6, 1, 2)]:
        pose = [x[i], y[j], z[k], *orientation]
        assert grid[i, j, k] == RUS6.reachable(pose)
    assert reachability_grid(RUS6, [0.0], [0.0], [0.0])[0, 0, 0]


def test_slices_agree_with_envelope():
    s = workspace_slices(RUS6, n=81)
    reach = {a.axis: a for a in ENVELOPE}
    centre = np.argmin(np.abs(s.x))
    assert s.x[centre] == pytest.approx(0.0, abs=1e-12)
    # along x through the centre of the z = 0 plane the reachable span is the surge reach
    xs = s.x[s.xy[:, centre]]
    step = s.x[1] - s.x[0]
    assert xs.max() == pytest.approx(reach["surge"].positive, abs=step)
    assert -xs.min() == pytest.approx(reach["surge"].negative, abs=step)
    zs = s.z[s.yz[centre, :]]
    assert -zs.min() == pytest.approx(reach["heave"].negative, abs=step)
    assert s.xy.shape == (81, 81) and s.xz.shape == (81, 81) and s.yz.shape == (81, 81)


def test_format_envelope_table():
    text = format_envelope(ENVELOPE)
    lines = text.splitlines()
    assert len(lines) == 8
    assert lines[2].split()[0] == "surge" and lines[-1].split()[0] == "yaw"
    # rotations in degrees to 0.1, translations in m to 0.001: the envelope's own values
    for line, a in zip(lines[2:], ENVELOPE, strict=True):
        scale, digits = (180.0 / math.pi, 0.05) if a.is_rotation else (1.0, 0.0005)
        assert float(line.split()[1]) == pytest.approx(scale * a.negative, abs=digits + 1e-9)
        assert float(line.split()[2]) == pytest.approx(scale * a.positive, abs=digits + 1e-9)
    assert lines[-1].split()[3] == "deg" and lines[2].split()[3] == "m"


def test_plot_writes_png(tmp_path):
    s = workspace_slices(RUS6, n=41)
    out = plot_rus6_workspace(s, tmp_path / "ws.png", envelope=ENVELOPE)
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000


def test_cli_workspace(tmp_path, capsys):
    png = tmp_path / "new" / "slices.png"  # its folder is made, as fly --out makes one
    assert main(["workspace", "--platform", "ceart", "--plot", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    out = capsys.readouterr().out
    assert "surge" in out and "yaw" in out and str(png) in out
    # the printed table is the preset's envelope (m and deg, rounded as printed)
    rows = {line.split()[0]: line.split()[1:3] for line in out.splitlines() if line.split()}
    for a in ENVELOPE:
        scale, digits = (180.0 / math.pi, 0.05) if a.is_rotation else (1.0, 0.0005)
        assert float(rows[a.axis][0]) == pytest.approx(scale * a.negative, abs=digits + 1e-9)
        assert float(rows[a.axis][1]) == pytest.approx(scale * a.positive, abs=digits + 1e-9)
    assert png.read_bytes()[:4] == b"\x89PNG"
    # a TOML path works too
    path = tmp_path / "g.toml"
    RUS6.geometry.to_toml(path)
    assert main(["workspace", "--platform", str(path)]) == 0
    # a bad platform is a one-line error with status 2
    assert main(["workspace", "--platform", "nope"]) == 2
    err = capsys.readouterr().err
    assert "unknown rus6 preset 'nope'" in err and len(err.strip().splitlines()) == 1


# --------------------------------------------------------------------------- planar: one default


def _planar_robot(capsys, *args: str) -> str:
    """The 3-RRR geometry ``motionbase workspace`` swept, by the name it printed."""
    assert main(["workspace", *args]) == 0
    out = capsys.readouterr().out
    first = out.splitlines()[0]
    assert first.startswith("3-RRR robot "), out
    return first.split("'")[1]


def _one_line_error(capsys, *args: str) -> str:
    assert main(["workspace", *args]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and len(captured.err.strip().splitlines()) == 1, captured.err
    return captured.err


def test_workspace_planar_honours_platform_and_rrr3(capsys):
    # --platform names the robot's geometry with --planar, as for `fly --planar`
    assert _planar_robot(capsys, "--planar", "--platform", "udesc_symmetric") == "udesc_symmetric"
    assert _planar_robot(capsys, "--planar", "--platform", "udesc") == "udesc"
    assert _planar_robot(capsys, "--planar", "--rrr3", "udesc") == "udesc"
    assert _planar_robot(capsys, "--planar", "--rrr3", "udesc_symmetric") == "udesc_symmetric"
    # the same geometry named twice is fine; two different ones are refused
    assert _planar_robot(capsys, "--planar", "--platform", "udesc", "--rrr3", "udesc") == "udesc"
    err = _one_line_error(capsys, "--planar", "--platform", "udesc", "--rrr3", "udesc_symmetric")
    assert "--platform" in err and "--rrr3" in err
    # --rrr3 without --planar would be silently unused: refused, saying what to add
    err = _one_line_error(capsys, "--rrr3", "udesc")
    assert "--planar" in err
    # a 6-RUS preset or robot is not a 3-RRR geometry: one line naming it and the flag to
    # drop, as fly --planar says it
    for value in ("ceart", "stewart6"):
        err = _one_line_error(capsys, "--planar", "--platform", value)
        assert value in err and "not a planar robot (drop --planar)" in err, err
        # given as --rrr3, the error named --platform, which nobody gave
        err = _one_line_error(capsys, "--planar", "--rrr3", value)
        assert f"--rrr3 {value}:" in err and "--platform" not in err.split(":", 2)[1], err


def test_planar_default_geometry_is_the_same_for_every_command(capsys, tmp_path):
    """`workspace --planar`, `fly --planar` and `teleop` use one default 3-RRR geometry."""
    from motionbase.io.mcap_source import read_metadata

    workspace = _planar_robot(capsys, "--planar")
    fly_out = tmp_path / "fly.mcap"
    assert main(["fly", "--planar", "--duration", "1", "--out", str(fly_out)]) == 0
    fly = read_metadata(fly_out)["pipeline_config"]["geometry"]["name"]
    csv = tmp_path / "cursor.csv"
    csv.write_text("t,x,y\n0.0,655,357\n0.5,655,357\n")
    teleop_out = tmp_path / "teleop.mcap"
    args = ["teleop", "--input", f"file:{csv}", "--duration", "0.5", "--out", str(teleop_out)]
    assert main(args) == 0
    teleop = read_metadata(teleop_out)["geometry"]["name"]
    assert workspace == fly == teleop == "udesc_symmetric"


# --------------------------------------------------------------------------- plot file formats


@pytest.mark.parametrize("planar", [False, True], ids=["rus6", "planar"])
def test_workspace_plot_is_written_in_the_format_its_extension_names(planar, tmp_path, capsys):
    flag = ["--planar"] if planar else []
    formats = (("svg", b"<?xml"), ("pdf", b"%PDF-"), ("png", b"\x89PNG"), ("PNG", b"\x89PNG"))
    for ext, magic in formats:
        path = tmp_path / f"ws.{ext}"
        assert main(["workspace", *flag, "--plot", str(path)]) == 0
        assert str(path) in capsys.readouterr().out
        data = path.read_bytes()
        assert data.startswith(magic), (ext, data[:16])
        if ext == "svg":
            assert b"<svg" in data[:2000]
    # an extension matplotlib would not honour, or none: refused before any work, one line
    for name in ("ws.jpeg", "ws.txt", "ws"):
        err = _one_line_error(capsys, "--plot", str(tmp_path / name), *flag)
        assert ".png, .svg or .pdf" in err
        assert not (tmp_path / name).exists()


def test_planar_workspace_figure_has_a_legend_naming_what_it_draws():
    from motionbase.io.planar_plots import planar_workspace_figure
    from motionbase.platform import Rrr3, Rrr3Geometry

    rrr3 = Rrr3(Rrr3Geometry.preset("udesc_symmetric"))
    ws = rrr3.workspace(30, 30, 13)
    rect = (0.11, 0.15, 0.07, 0.10)
    fig = planar_workspace_figure(rrr3, ws, rectangle=rect)
    assert len(fig.legends) == 1
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    for what in ("valid pose", "base triangle", "motors", "home", "platform at home"):
        assert any(what in label for label in labels), (what, labels)
    assert any("rectangle" in label for label in labels)
    # the legend's entries are the drawn data: the home marker sits at the robot's home pose
    slice_ax = fig.axes[1]
    home = next(ln for ln in slice_ax.get_lines() if ln.get_label() == "home")
    np.testing.assert_allclose(np.r_[home.get_xdata(), home.get_ydata()], rrr3.home[:2])
    box = next(ln for ln in slice_ax.get_lines() if "rectangle" in ln.get_label())
    assert (min(box.get_xdata()), max(box.get_xdata())) == rect[:2]
    assert (min(box.get_ydata()), max(box.get_ydata())) == rect[2:]


def test_a_planar_workspace_too_small_for_a_rectangle_is_still_swept_and_drawn(tmp_path, capsys):
    """Servos of 2 deg range: home is reachable (``fly --planar`` runs with the file), but no
    4 x 4 block of the grids is valid. ``workspace --planar`` failed as a whole on the
    decoration it draws, the calibration's rectangle, with "no usable workspace rectangle
    at phi = 0 rad", naming neither the file nor a fix."""
    from motionbase.platform.robot import load_geometry
    from motionbase.platform.rrr3 import Rrr3

    preset = Path(__file__).parents[1] / "src/motionbase/presets/rrr3_udesc_symmetric.toml"
    text = preset.read_text()
    text = re.sub(r"(?m)^min_deg = .*$", "min_deg = [88, 88, 88]", text)
    text = re.sub(r"(?m)^max_deg = .*$", "max_deg = [90, 90, 90]", text)
    path = tmp_path / "narrow.toml"
    path.write_text(text)
    _, geometry = load_geometry(str(path), planar=True)
    kin = Rrr3(geometry)
    assert kin.reachable(np.asarray(kin.home))  # a robot that works, in a small space
    plot = tmp_path / "narrow.png"
    assert main(["workspace", "--planar", "--platform", str(path), "--plot", str(plot)]) == 0
    out = capsys.readouterr().out
    assert "largest rectangle at phi = 0: none" in out
    assert plot.stat().st_size > 1000


@pytest.mark.parametrize("platform", ["rus6", "stewart6", "long_rods"])
def test_the_default_slices_show_the_whole_reachable_region(platform, tmp_path):
    """The grids spanned 1.25 x the largest single-axis reach, but axes combined reach
    further: a 6-RUS with 1.2 m rods and 0.1 m cranks (a user's geometry) was cut off at
    the plot's edge in its side and front views. No slice may touch its grid's border,
    and nothing may be reachable one grid step past the side view's edges."""
    from motionbase.platform.robot import load_geometry, robot_spec

    if platform == "long_rods":
        preset = Path(__file__).parents[1] / "src/motionbase/presets/rus6_ceart.toml"
        text = re.sub(r"(?m)^rod = .*$", "rod = 1.2", preset.read_text())
        text = re.sub(r"(?m)^crank = .*$", "crank = 0.1", text)
        platform = str(tmp_path / "long_rods.toml")
        Path(platform).write_text(text)
    name, geometry = load_geometry(platform)
    robot = robot_spec(name).make(geometry)
    s = workspace_slices(robot, n=121)
    for grid in (s.xy, s.xz, s.yz):
        assert grid.any()
        assert not (grid[0].any() or grid[-1].any() or grid[:, 0].any() or grid[:, -1].any())
    edge = s.x[-1] + (s.x[1] - s.x[0])
    zs = np.linspace(s.z[0], s.z[-1], 481)
    for x in (-edge, edge):
        poses = np.zeros((zs.size, 6))
        poses[:, 0], poses[:, 2] = x, zs
        assert not np.asarray(robot.reachable(poses)).any()


def test_a_large_platform_reaches_beyond_the_first_scan(tmp_path):
    """The translation scans stopped at 2 m and gave 2.000 m as the reach of any platform
    reaching further: a hexapod with 3 m legs and a 3.5 m stroke printed surge, sway and
    heave up "2.000". Each bound must be an edge: reachable from neutral up to it, not
    just past it."""
    from motionbase.platform.robot import load_geometry, robot_spec

    preset = Path(__file__).parents[1] / "src/motionbase/presets/stewart6_seat.toml"
    text = preset.read_text()
    for key, value in (
        ("base_radius", 2.0), ("platform_radius", 1.4), ("neutral_length", 3.0),
        ("length_min", 1.5), ("length_max", 5.0),
    ):  # fmt: skip
        text = re.sub(rf"(?m)^{key} = \S+", f"{key} = {value}", text)
    path = tmp_path / "big.toml"
    path.write_text(text)
    name, geometry = load_geometry(str(path))
    robot = robot_spec(name).make(geometry)
    envelope = single_axis_envelope(robot, tol=1e-7)
    assert max(envelope[0].negative, envelope[0].positive) > 2.5  # surge
    for j, a in enumerate(envelope[:3]):
        for sign, edge in ((-1.0, a.negative), (1.0, a.positive)):
            path = np.zeros((2001, 6))
            path[:, j] = sign * np.linspace(0.0, edge - 1e-6, 2001)
            assert np.asarray(robot.reachable(path)).all(), (a.axis, sign)
            beyond = np.zeros(6)
            beyond[j] = sign * (edge + 1e-5)
            assert not robot.reachable(beyond), (a.axis, sign, edge)


def test_the_planar_sweep_holds_a_workspace_that_leaves_the_base_triangle(tmp_path):
    """The default sweep covered the base triangle's bounding box only; with cranks of
    0.07 m and rods of 0.14 m (a user's 3-RRR on the thesis's base) valid poses lie up to
    3 cm below y = 0, and ``workspace --planar`` cut them off its plot and its figures.
    Every valid position of a sweep over a box three times as large must lie inside the
    default sweep's box."""
    from motionbase.platform.robot import load_geometry
    from motionbase.platform.rrr3_workspace import workspace_sweep

    preset = Path(__file__).parents[1] / "src/motionbase/presets/rrr3_udesc_symmetric.toml"
    text = re.sub(r"(?m)^crank = \S+", "crank = 0.07", preset.read_text())
    text = re.sub(r"(?m)^rod = \S+", "rod = 0.14", text)
    path = tmp_path / "long_links.toml"
    path.write_text(text)
    _, geometry = load_geometry(str(path), planar=True)
    side = geometry.base_side
    wide = workspace_sweep(geometry, 150, 150, 37, x_range=(-side, 2 * side),
                           y_range=(-side, 2 * side))  # fmt: skip
    xi, yi = np.nonzero(wide.total)
    assert wide.y[yi].min() < -0.01  # the workspace does leave the triangle's box
    default = workspace_sweep(geometry, 100, 100, 37)
    assert default.x[0] <= wide.x[xi].min() and wide.x[xi].max() <= default.x[-1]
    assert default.y[0] <= wide.y[yi].min() and wide.y[yi].max() <= default.y[-1]
    # and the thesis's robot is swept over its base triangle's box, as before
    _, thesis = load_geometry("udesc_symmetric", planar=True)
    ws = workspace_sweep(thesis, 10, 10, 3)
    assert (ws.x[0], ws.x[-1], ws.y[0]) == (0.0, side, 0.0)
    assert ws.y[-1] == pytest.approx(side * math.sqrt(3) / 2)
