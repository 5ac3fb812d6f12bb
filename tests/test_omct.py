"""The objective motion cueing test (``motionbase omct``): the measurement chain and the analysis.

Every test runs the real pipeline (compiled 6-RUS tick, or the stage-by-stage path), the
robot's forward kinematics and the perception module's specific force and body rates; the
expectations come from physics and from the z-domain (discretisation), never from the
numbers the OMCT prints.
"""

from __future__ import annotations

import dataclasses
import json
import math
import re

import numpy as np
import pytest
from matplotlib.image import imread
from scipy.special import j1

from motionbase import omct
from motionbase.app import load_config
from motionbase.cli import build_parser, main
from motionbase.errors import ConfigError
from motionbase.io.omct_plots import write_omct
from motionbase.pipeline import PipelineConfig
from motionbase.platform import Rus6, Rus6Geometry
from motionbase.platform.rus6_workspace import single_axis_envelope
from motionbase.washout import WashoutParams
from motionbase.washout.cueing import Cueing

G = 9.80665


class PureGain(Cueing):
    """A test cueing plug-in: the platform follows the aircraft one to one.

    The specific force deviation from level flight is the platform's acceleration and the
    body rates are its Euler rates, each integrated by the trapezoidal rule from rest; no
    washout, no tilt. It implements the cueing plug-in interface in Python (no compiled
    kernels) and is given to the pipeline in place of the classical washout
    (``omct.simulate(..., cueing=...)``), since the classical washout cannot be made a pure
    gain (its translational channel always washes out).

    Through the OMCT's central differences the chain is then exactly
    ``(z + 2 + 1/z)/4 = (1 + cos(w dt))/2`` at every frequency: real, so phase 0, and
    ``1 - (w dt)^2/4`` to second order (0.4 % at 15.85 rad/s and 120 Hz).
    """

    name = "pure_gain"

    def __init__(self, dt: float) -> None:
        self.params = None
        self.dt = dt
        self.tracked = 0
        self.reset()

    def reset(self) -> None:
        self.x = np.zeros(3)
        self.v = np.zeros(3)
        self.a = np.zeros(3)
        self.angle = np.zeros(3)
        self.rate = np.zeros(3)

    def advance(self, u, out) -> bool:
        h = self.dt / 2.0
        a = u[:3] - (0.0, 0.0, -G)
        w = np.array(u[3:], dtype=float)  # a copy: the pipeline reuses its array
        v = self.v + h * (a + self.a)
        self.x = self.x + h * (v + self.v)
        self.v, self.a = v, a
        self.angle = self.angle + h * (w + self.rate)
        self.rate = w
        out[:3] = self.x
        out[3:] = self.angle
        return True

    def track(self, achieved_pose) -> None:
        self.tracked += 1


# A full-size 6-RUS written out here (the shape of the ceart preset when this test was
# written), so that the tests do not move when the shipped preset does.
_PAIRS = [math.radians(a) for a in (30.0, 30.0, -90.0, -90.0, 150.0, 150.0)]
_BASE = {
    "name": "test rus6", "rb": 0.35195, "d": 0.2032, "rp": 0.39392, "e": 0.069459,
    "chi_a": _PAIRS, "chi_j": _PAIRS,
    "beta": [math.radians(a) for a in (150.0, -90.0, 30.0, 150.0, -90.0, 30.0)],
    "crank": 0.184, "rod": 0.724, "neutral_angle_deg": 0.0,
    "angle_min": -math.radians(60.0), "angle_max": math.radians(60.0),
    "park_angle": -math.radians(55.0), "max_speed": 3.0, "max_accel": 30.0,
}  # fmt: skip


def _geometry(**changes) -> Rus6Geometry:
    return Rus6Geometry.from_dict({**_BASE, **changes})


def _huge() -> Rus6Geometry:
    """The test platform ten times larger, cranks +-85 deg, speed and acceleration far away."""
    big = {k: 10.0 * _BASE[k] for k in ("rb", "d", "rp", "e", "crank", "rod")}
    lim = math.radians(85.0)
    return _geometry(
        **big, name="huge", angle_min=-lim, angle_max=lim, max_speed=100.0, max_accel=1e5,
    )  # fmt: skip


def _complex_error(measured: np.ndarray, reference: np.ndarray) -> np.ndarray:
    return np.abs(measured - reference) / np.abs(reference)


# --------------------------------------------------------------------------- measurement chain


def test_pure_gain_through_a_huge_platform_gives_gain_one_and_phase_zero():
    config = PipelineConfig("rus6", _huge(), WashoutParams.preset("default"))
    dt = config.dt
    freqs = omct.FREQUENCIES[[6, 9, 11]]  # 1.58, 6.31, 15.85 rad/s (a metre of travel at most)
    cueings = []

    def factory():
        cueings.append(PureGain(dt))
        return cueings[-1]

    result = omct.run_omct(
        config, frequencies=freqs, cueing=factory, cueing_name="pure gain", settle_s=0.0
    )
    exact = (1.0 + np.cos(freqs * dt)) / 2.0  # the discretisation (PureGain docstring)
    for name in ("roll", "pitch", "yaw", "surge", "sway", "heave"):
        r = result[name]
        assert r.linear is None
        assert (r.clamped == 0).all() and (r.limited == 0).all(), name
        assert np.abs(r.gain - 1.0).max() <= (freqs.max() * dt) ** 2 / 4 + 1e-6, name
        np.testing.assert_allclose(r.gain, exact, rtol=1e-6, err_msg=name)
        np.testing.assert_allclose(r.phase_deg, 0.0, atol=1e-4, err_msg=name)
    assert sum(c.tracked for c in cueings) == 0

    # The platform rotates one to one and nothing cancels the gravity component of its tilt:
    # a cab pitched by theta feels g sin(theta) forward, rolled by phi -g sin(phi) sideways.
    # The fundamental of g sin(A' sin(w t)) is 2 g J1(A'); A' is the trapezoid-integrated
    # attitude amplitude, A (w dt/2) cot(w dt/2).
    amp = result.amplitudes
    for name, sign in (("pitch->surge", 1.0), ("roll->sway", -1.0)):
        r = result[name]
        a_in = np.minimum(amp.angle, amp.rate / freqs)
        a_platform = a_in * (freqs * dt / 2) / np.tan(freqs * dt / 2)
        expected = sign * 2.0 * G * j1(a_platform) / a_in
        np.testing.assert_allclose(r.response.real, expected, rtol=1e-5, err_msg=name)
        np.testing.assert_allclose(r.response.imag, 0.0, atol=1e-5 * G, err_msg=name)
    # a pure-gain cueing does not tilt for a specific force
    for name in ("surge->pitch", "sway->roll"):
        assert result[name].gain.max() < 1e-9


def test_fourier_coefficients_are_those_of_whole_periods():
    w = 1.3
    t = np.arange(0, 4 * 2 * np.pi / w, 0.01)
    y = 0.7 * np.cos(w * t + 0.4) + 3.0 + 0.2 * np.cos(3 * w * t - 1.0)
    assert omct.phasor(y, t, w) == pytest.approx(0.7 * np.exp(0.4j), abs=1e-3)


# --------------------------------------------------------------------------- classical washout


@pytest.fixture(scope="module")
def default_ceart():
    return omct.run_omct(load_config(platform="ceart", washout="default"))


def test_classical_washout_matches_its_linear_response_where_no_limit_acts(default_ceart):
    result = default_ceart
    assert len(result.results) == 10 and not result.not_applicable
    dt = result.config.dt
    for r in result.results:
        assert (r.clamped == 0).all() and (r.limited == 0).all(), r.test.name
        # the discrete chain's response (z-domain): only the numerics of the measurement
        assert _complex_error(r.response, r.linear).max() < 2e-4, r.test.name
        # the continuous design: the Tustin warping and the central differences, of the
        # order of (w dt)^2 (at most 2 % at 15.85 rad/s, 120 Hz)
        tol = 1.5 * (r.frequencies * dt) ** 2 + 1e-4
        assert (_complex_error(r.response, r.design) <= tol).all(), r.test.name
        assert not r.deviates().any(), r.test.name


def test_linear_response_has_the_washout_s_asymptotes():
    """Independent of the simulation: limits of the analytic response at both ends."""
    p = WashoutParams.preset("default")
    lo, hi = np.array([1e-4]), np.array([1e4])
    for name in ("roll", "pitch", "yaw", "heave"):
        k = p.angular_velocity_gain if name in ("roll", "pitch", "yaw") else p.specific_force_gain
        i = {"roll": 0, "pitch": 1, "yaw": 2, "heave": 2}[name]
        assert abs(omct.classical_response(p, name, lo)[0]) < 1e-6  # high-passed
        assert omct.classical_response(p, name, hi)[0] == pytest.approx(k[i], rel=1e-3)
    # surge: the tilt renders the sustained force, the translation the onsets; planar: no tilt
    assert omct.classical_response(p, "surge", lo)[0] == pytest.approx(0.5, rel=1e-3)
    assert omct.classical_response(p, "surge", hi)[0] == pytest.approx(0.5, rel=1e-3)
    assert abs(omct.classical_response(p, "surge", lo, tilt=False)[0]) < 1e-6
    # tilt coordination: K/g rad per m/s^2, nose up for a forward force, left wing down for
    # a force to the right
    assert omct.classical_response(p, "surge->pitch", lo)[0] == pytest.approx(0.5 / G, rel=1e-3)
    assert omct.classical_response(p, "sway->roll", lo)[0] == pytest.approx(-0.5 / G, rel=1e-3)
    # no roll tilt (roll's angle limit 0): a sustained sway force is washed out, while
    # surge keeps its pitch tilt
    q = dataclasses.replace(p, tilt_angle_limit_deg=(0.0, 8.0))
    assert abs(omct.classical_response(q, "sway", lo)[0]) < 1e-6
    assert abs(omct.classical_response(q, "sway->roll", lo)[0]) < 1e-6
    assert omct.classical_response(q, "sway", hi)[0] == pytest.approx(0.5, rel=1e-3)
    assert omct.classical_response(q, "surge", lo)[0] == pytest.approx(0.5, rel=1e-3)


def test_the_linear_response_includes_the_input_low_pass():
    """A file with an [input] low-pass (the telemetry preset: 8 rad/s) filters every channel
    first. Its linear response was drawn without it, so omct --params telemetry marked every
    point '*' (a limit acts) with nothing clamped or limited."""
    p = WashoutParams.preset("telemetry")
    assert p.input_lowpass_wn == 8.0
    w = np.array([1.0, 4.0, 10.0])
    s = 1j * w
    # the continuous design by hand: yaw rate K_w s^2/(s^2 + 2 zeta wn s + wn^2), heave
    # K_f s^3/((s^2 + 2 zeta wn s + wn^2)(s + wb)), each after 8^2/(s + 8)^2
    pre = 64.0 / (s + 8.0) ** 2
    yaw = 0.3 * s**2 / (s**2 + 3.0 * s + 2.25)
    heave = 0.35 * s**3 / ((s**2 + 10.0 * s + 25.0) * (s + 0.5))
    np.testing.assert_allclose(omct.classical_response(p, "yaw", w), pre * yaw, rtol=1e-12)
    np.testing.assert_allclose(omct.classical_response(p, "heave", w), pre * heave, rtol=1e-12)
    # the low-pass's pole (8 rad/s) is not the slowest: the settling time is the washout's
    assert omct.slowest_decay(p) == pytest.approx(0.5)
    # measured through the whole chain at half the amplitudes (nothing limits): on the line
    config = load_config(platform="ceart", washout="telemetry")
    result = omct.run_omct(
        config, frequencies=w, tests=["yaw", "heave"], amplitudes=omct.Amplitudes().scaled(0.5)
    )
    for r in result.results:
        assert (r.clamped == 0).all() and (r.limited == 0).all(), r.test.name
        assert _complex_error(r.response, r.linear).max() < 2e-4, r.test.name
        assert not r.deviates().any(), r.test.name


def test_tight_crank_limits_lower_the_gain_where_the_linear_motion_exceeds_the_reach():
    lim = math.radians(4.0)
    geometry = _geometry(name="tight", angle_min=-lim, angle_max=lim, park_angle=-math.radians(3.0))
    reach = next(a for a in single_axis_envelope(Rus6(geometry)) if a.axis == "yaw")
    r_yaw = min(reach.negative, reach.positive)
    config = PipelineConfig("rus6", geometry, WashoutParams.preset("default"))
    # 20 deg of aircraft yaw, the rate capped at 18 deg/s: inside the washout's 20 deg/s limit
    amplitudes = omct.Amplitudes(angle=math.radians(20.0), rate=math.radians(18.0))
    result = omct.run_omct(config, amplitudes=amplitudes, tests=["yaw"])
    r = result["yaw"]
    w = r.frequencies
    # the platform's yaw amplitude if nothing limited it (angle = rate / w)
    linear_yaw = np.abs(r.linear) * r.input_amplitude / w
    inside, beyond = linear_yaw < 0.95 * r_yaw, linear_yaw > 1.05 * r_yaw
    assert inside.sum() >= 6 and beyond.sum() >= 2  # both regimes are tested
    # inside the reach the chain stays linear
    assert (r.clamped[inside] == 0).all()
    assert _complex_error(r.response[inside], r.linear[inside]).max() < 2e-4
    # beyond it the clamp acts and the gain drops; the fundamental of a yaw angle bounded by
    # the reach R is at most 4 R / pi (the square wave's), whatever the washout does
    assert (r.clamped[beyond] > 0).all()
    assert (r.gain[beyond] < 0.97 * np.abs(r.linear[beyond])).all()
    measured_yaw = (
        r.gain * r.input_amplitude * (w * result.config.dt) / np.sin(w * result.config.dt) / w
    )
    assert (measured_yaw[beyond] <= 4.0 / np.pi * r_yaw * 1.001).all()


def test_planar_robot_runs_the_tests_it_renders():
    config = load_config(planar=True)
    freqs = omct.FREQUENCIES[[7, 10]]  # 2.5 and 10 rad/s
    result = omct.run_omct(config, frequencies=freqs, tests=["surge", "pitch", "sway->roll"])
    assert [r.test.name for r in result.results] == ["surge"]
    assert result.not_applicable == ("pitch", "sway->roll")
    r = result["surge"]
    # no tilt on the planar robot: what it renders is the washout's translation alone
    np.testing.assert_allclose(
        r.linear,
        omct.classical_response(config.cueing_params, "surge", freqs, tilt=False, dt=config.dt),
    )
    assert (r.clamped == 0).all() and (r.limited == 0).all()
    assert _complex_error(r.response, r.linear).max() < 2e-4
    assert "not applicable" in result.table_text()


# --------------------------------------------------------------------------- files and CLI


def test_omct_command_writes_table_json_and_bode_plots(tmp_path, capsys):
    out = tmp_path / "omct"
    # 30 Hz keeps the run short; the OMCT needs at least 21 Hz for 15.85 rad/s; the SIMONA
    # set stays linear at these amplitudes (the tuned default's tilt rate limit acts above
    # 2 rad/s)
    assert main(["omct", "--rate", "30", "--params", "default", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "pitch->surge" in printed and f"in {out}" in printed
    data = json.loads((out / "omct.json").read_text())
    assert data["rate_hz"] == 30.0 and data["not_applicable"] == []
    assert set(data["tests"]) == {t.name for t in omct.TESTS}
    surge = data["tests"]["surge"]
    assert len(surge["gain"]) == 12
    assert np.allclose(surge["gain"], surge["linear_gain"], rtol=1e-3)
    table = (out / "table.md").read_text()
    assert f"`motionbase omct --params default --rate 30 --out {out}`" in table
    assert table.count("\n| ") == 13  # header and 12 frequencies
    for test in omct.TESTS:
        img = imread(out / f"bode_{test.name.replace('->', '-')}.png")
        assert img.shape[0] > 300 and img.std() > 0.05


def test_write_omct_without_a_linear_reference(tmp_path):
    config = PipelineConfig("rus6", _huge(), WashoutParams.preset("default"))
    result = omct.run_omct(
        config, frequencies=[3.0], tests=["yaw"], settle_s=0.0,
        cueing=lambda: PureGain(config.dt), cueing_name="pure gain",
    )  # fmt: skip
    files = write_omct(result, tmp_path)
    data = json.loads((tmp_path / "omct.json").read_text())
    assert data["cueing"] == "pure gain" and data["tests"]["yaw"]["linear_gain"] is None
    assert "*" not in (tmp_path / "table.md").read_text().split("\n\n")[0]
    assert len([f for f in files.files if f.suffix == ".png"]) == 1


def test_an_earlier_tests_plots_do_not_stay_beside_a_new_ones(tmp_path):
    """``omct --out DIR`` over the folder of an earlier test with other channels kept that
    test's Bode plots beside the new ones, where they read as this test's. They are removed;
    a file of the user's there is kept."""
    config = PipelineConfig("rus6", _huge(), WashoutParams.preset("default"))

    def measure(test: str) -> omct.OmctResult:
        return omct.run_omct(
            config, frequencies=[3.0], tests=[test], settle_s=0.0,
            cueing=lambda: PureGain(config.dt), cueing_name="pure gain",
        )  # fmt: skip

    write_omct(measure("yaw"), tmp_path)
    (tmp_path / "notes.txt").write_text("mine")
    (tmp_path / "bode_mine.png").write_bytes(b"mine")
    assert (tmp_path / "bode_yaw.png").exists()
    write_omct(measure("roll"), tmp_path)
    plots = sorted(p.name for p in tmp_path.glob("*.png"))
    assert plots == ["bode_mine.png", "bode_roll.png"], plots
    assert (tmp_path / "notes.txt").read_text() == "mine"
    assert list(json.loads((tmp_path / "omct.json").read_text())["tests"]) == ["roll"]


def test_params_is_the_washout_file_option():
    args = build_parser().parse_args(["omct", "--params", "mine.toml", "--out", "d"])
    assert args.washout == "mine.toml"


@pytest.mark.parametrize(
    "argv, words",
    [
        (["omct"], "--out"),
        (["omct", "--out", ""], "--out: empty"),  # an unset $DIR: not the current folder
        (["omct", "--out", "D", "--washout", "nonexistent"], "nonexistent"),
        (["omct", "--out", "D", "--rate", "15"], "too low"),
        (["omct", "--out", "D", "--scale", "-1"], "--scale"),
        (["omct", "--out", "D", "--scale", "200"], "lower the amplitudes"),
        # the signals lost in rounding: gains of 1e268, then a traceback from the plots
        (["omct", "--out", "D", "--scale", "1e-300"], "--scale 1e-300"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(argv, words, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exc:
        raise SystemExit(main(argv))
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and words in err
    assert not (tmp_path / "D").exists()


def test_the_command_refuses_an_out_that_is_a_file_before_it_runs(tmp_path, capsys):
    """Said at once, before the minutes of the test (not "File exists" at their end)."""
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["omct", "--rate", "30", "--out", str(blocker / "sub")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (
        f"motionbase omct: error: --out {blocker / 'sub'}: {blocker} is not a folder "
        "(choose another --out path)"
    )
    assert blocker.read_text() == "x"


def test_out_that_is_a_file_is_one_line(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    config = load_config(rate_hz=30.0)
    result = omct.run_omct(config, frequencies=[5.0], tests=["yaw"])
    from motionbase.errors import SinkError

    with pytest.raises(SinkError, match="is not a folder"):
        write_omct(result, blocker)


def test_an_mpc_whose_solver_failed_says_so_in_the_table():
    """An MPC that fell back on every tick (one iteration never solves) measures its
    fallback washout's response, which the table printed as the MPC's without a word. The
    table, and the JSON file, now say on how many ticks the solver failed; an MPC that
    solved says nothing."""
    from motionbase.washout.mpc_params import MpcParams

    failing = dataclasses.replace(MpcParams.load("tuned_ceart"), max_iter=1)
    for params, failed in ((failing, True), (MpcParams.load("tuned_ceart"), False)):
        config = dataclasses.replace(load_config(cueing="mpc"), cueing_params=params)
        result = omct.run_omct(config, frequencies=[1.0], tests=["surge"], settle_s=1.0)
        warnings = [line for line in result.table_text().splitlines() if "fell back" in line]
        fallbacks, ticks = result.to_dict()["cueing_fallbacks"]
        # (at rest, before the sinusoid starts, one iteration may be enough)
        assert ticks > 0 and (fallbacks > ticks // 2 if failed else fallbacks == 0), fallbacks
        assert len(warnings) == int(failed), warnings
        if failed:
            assert f"{fallbacks} of {ticks} ticks" in warnings[0], warnings
            assert "tuned_ceart" in warnings[0]  # the washout measured instead


def test_the_rate_the_too_low_message_asks_for_is_accepted():
    """At 20 Hz the message said "at least 20 Hz" for 15.85 rad/s and refused 20 Hz (it
    needs 8 samples a period: 4 x 15.85 / pi = 20.2 Hz, printed rounded down)."""
    w = omct.FREQUENCIES[-1]
    config = load_config(planar=False, platform=None, washout="default", rate_hz=20.0)
    with pytest.raises(ConfigError, match="too low") as exc:
        omct.run_omct(config, frequencies=[w], tests=["yaw"], settle_s=0.0)
    asked = float(re.search(r"at least ([0-9.]+) Hz", str(exc.value)).group(1))
    assert asked >= 8 * w / (2 * math.pi)  # 8 samples per period, counted independently
    config = load_config(planar=False, platform=None, washout="default", rate_hz=asked)
    result = omct.run_omct(config, frequencies=[w], tests=["yaw"], settle_s=0.0)
    assert result["yaw"].gain[0] > 0


def test_a_channel_switched_off_is_not_marked_as_a_limit_acting():
    """With a gain of 0 (roll's angular_velocity_gain, heave's specific_force_gain) the
    channel is off: the platform does not move in it, and the linear response is 0. The
    measurement reads the chain's rounding (1e-15), which was marked "*" (a limit acts)
    at every frequency, since any difference from 0 exceeded 5 % of 0."""
    base = WashoutParams.preset("default")
    params = dataclasses.replace(
        base,
        angular_velocity_gain=(0.0, *base.angular_velocity_gain[1:]),
        specific_force_gain=(*base.specific_force_gain[:2], 0.0),
    )
    config = PipelineConfig("rus6", Rus6Geometry.preset("ceart"), params)
    result = omct.run_omct(
        config, frequencies=[0.3, 3.0], tests=["roll", "roll->sway", "heave"], settle_s=3.0
    )
    for r in result.results:
        assert (r.gain < 1e-9).all(), (r.test.name, r.gain)  # nothing moves in the channel
        assert not r.deviates().any(), r.test.name
    assert "*" not in result.markdown().split("\n\n")[0]


def test_the_bode_plot_of_a_channel_switched_off_draws_its_zeros_without_a_warning():
    """All gains 0 (roll with angular_velocity_gain 0): the log gain axis had nothing
    positive and matplotlib printed "UserWarning: Data has no positive values" on the
    terminal of ``motionbase omct``; the zeros are now drawn on a linear gain axis."""
    import warnings

    from motionbase.io.omct_plots import bode_figure

    base = WashoutParams.preset("default")
    params = dataclasses.replace(base, angular_velocity_gain=(0.0, *base.angular_velocity_gain[1:]))
    config = PipelineConfig("rus6", Rus6Geometry.preset("ceart"), params)
    result = omct.run_omct(config, frequencies=[0.3, 3.0], tests=["roll", "pitch"], settle_s=1.0)
    assert (result["roll"].gain == 0).all()  # the platform does not roll at all
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        roll = bode_figure(result, result["roll"])
        roll.canvas.draw()
        pitch = bode_figure(result, result["pitch"])
        pitch.canvas.draw()
    assert roll.axes[0].get_yscale() == "linear"
    assert pitch.axes[0].get_yscale() == "log" and pitch.axes[0].get_xscale() == "log"
    # the measured zeros are on the roll plot, at the test frequencies
    xy = roll.axes[0].lines[-1].get_xydata()
    np.testing.assert_array_equal(xy, [[0.3, 0.0], [3.0, 0.0]])


def test_printed_phases_stay_in_the_stated_range_without_a_negative_zero():
    """Phases are in (-180, 180] deg; rounded for print, -179.7 came out "-180" and -0.3
    "-0" (the MPC's table: "0.44 ∠-0"). The printed value must be the rounded phase in
    that range: 180 and 0."""
    config = PipelineConfig("rus6", Rus6Geometry.preset("ceart"), WashoutParams.preset("default"))
    phases = np.radians([-0.3, -179.7, -179.96, 90.0])
    tr = omct.TestResult(
        test=omct._test("yaw"),
        frequencies=np.array([0.5, 1.0, 2.0, 4.0]),
        input_amplitude=np.full(4, 0.1),
        response=0.5 * np.exp(1j * phases),
        linear=0.5 * np.exp(1j * phases),
        clamped=np.zeros(4),
        limited=np.zeros(4),
    )
    result = omct.OmctResult(
        results=(tr,), not_applicable=(), config=config, amplitudes=omct.Amplitudes(),
        settle_s=0.0, discard_periods=np.ones(4, int), measure_periods=np.full(4, 2),
    )  # fmt: skip
    cells = [line.split("|")[2].strip() for line in result.markdown().splitlines()[2:6]]
    assert cells == ["0.5 ∠0", "0.5 ∠180", "0.5 ∠180", "0.5 ∠90"]
    rows = result.table_text().splitlines()[4:8]
    assert [row.split()[2] for row in rows] == ["-0.3", "-179.7", "180.0", "90.0"]
    assert [row.split()[4] for row in rows] == ["-0.3", "-179.7", "180.0", "90.0"]


def test_a_washout_that_never_settles_is_refused_before_it_fills_the_memory(capsys, tmp_path):
    """A translational zeta of 1e-6 (valid: > 0) puts a pole 1.7e-6 1/s from the axis; the
    test discarded 10 time constants, 5.9e6 s, and set out to simulate 7e8 ticks per run:
    24 GB in under a minute, then the machine's memory. It must be a one-line error
    naming the settling time and the fix, said at once."""
    base = WashoutParams.preset("default")
    zeta = (1e-6, *base.translational_zeta[1:])
    params = dataclasses.replace(base, translational_zeta=zeta)
    decay = 1e-6 * base.translational_wn[0]  # -Re(pole) of the lightly damped pair, 1/s
    config = PipelineConfig("rus6", Rus6Geometry.preset("ceart"), params)
    with pytest.raises(ConfigError) as exc:
        omct.run_omct(config)
    message = str(exc.value)
    settle = float(re.search(r"needs ([0-9.e+]+) s to settle", message).group(1))
    assert settle == pytest.approx(10.0 / decay, rel=1e-2)
    assert "zeta" in message and "--rate" in message and "\n" not in message
