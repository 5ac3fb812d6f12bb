"""The tuner (``motionbase tune``): its score, its optimiser, its file, where it runs.

Manoeuvres are short windows of real JSBSim scripts (a few seconds each) and budgets a
few evaluations, so that the whole file runs in well under a minute.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import math
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from signalled import signalled

from motionbase import app, cli, tuning
from motionbase.config import preset_path
from motionbase.io.executors import open_evaluator
from motionbase.io.manoeuvres import (
    DEFAULT_HOLDOUT,
    DEFAULT_MANOEUVRES,
    Manoeuvre,
    load_recording,
    load_script,
    parse_script_spec,
)
from motionbase.platform import Rus6Geometry, Stewart6Geometry
from motionbase.platform.stewart6 import Stewart6Robot
from motionbase.report import robot_reach, rus6_reach
from motionbase.stopping import Stopped, StopRequest
from motionbase.washout import WashoutParams
from motionbase.washout.perception import (
    perceived_angular_velocity,
    perceived_specific_force,
    platform_angular_velocity,
    platform_specific_force,
)

G = 9.80665


@pytest.fixture(scope="module")
def ceart():
    geometry = Rus6Geometry.preset("ceart")
    return geometry, rus6_reach(geometry)


@pytest.fixture(scope="module")
def kick() -> Manoeuvre:
    """The 737's rudder kick, first 6 s (a yaw-roll onset into a sideslip)."""
    return load_script("rudder_kick@0:6")


@pytest.fixture(scope="module")
def takeoff() -> Manoeuvre:
    """The C172's take-off run, 4-10 s (full throttle, turning on the ground)."""
    return load_script("c1723@4:10")


def _zero_gains(p: WashoutParams) -> WashoutParams:
    return dataclasses.replace(p, specific_force_gain=(0, 0, 0), angular_velocity_gain=(0, 0, 0))


# --------------------------------------------------------------------------- manoeuvres


def test_default_set_is_five_varied_scripts_and_a_disjoint_holdout():
    assert len(DEFAULT_MANOEUVRES) >= 5
    names = {parse_script_spec(s)[0] for s in DEFAULT_MANOEUVRES}
    assert {"c172_elevator_doublet", "737_cruise_steady_turn", "rudder_kick"} <= names
    assert not {s for s in DEFAULT_HOLDOUT} & set(DEFAULT_MANOEUVRES)


def test_script_window_keeps_the_samples_between_start_and_end(kick):
    assert kick.rate_hz == pytest.approx(120.0, rel=1e-4)  # the script's dt, 0.008333 s
    assert kick.t[0] == pytest.approx(kick.dt, abs=1e-9)  # JSBSim's first sample is after dt
    assert kick.t[-1] == pytest.approx(6.0, abs=kick.dt)
    late = load_script("rudder_kick@3:6")
    assert late.t[0] == pytest.approx(3.0, abs=kick.dt)
    # the same flight: the window is a slice of it, not a new run from another start
    i = int(np.searchsorted(kick.t, late.t[0] - 1e-9))
    np.testing.assert_array_equal(late.specific_force, kick.specific_force[i:])


def test_recording_reads_the_aircraft_states_of_the_flight_it_recorded():
    # recordings/c1723_30s.mcap is `motionbase fly c1723 --duration 30`: its /aircraft/state
    # is the same JSBSim flight, sample for sample
    rec = load_recording("recordings/c1723_30s.mcap")
    flown = load_script("c1723@0:30")
    assert rec.rate_hz == pytest.approx(flown.rate_hz)
    assert len(rec) == len(flown)
    np.testing.assert_array_equal(rec.specific_force, flown.specific_force)
    np.testing.assert_array_equal(rec.angular_velocity, flown.angular_velocity)


def test_held_out_manoeuvres_share_no_samples_with_the_tuning_set(tmp_path):
    """A held-out manoeuvre holds samples of a tuning one when it is a window of the same
    script that overlaps it, or the same file by another path; windows that do not overlap
    and other flights are held out."""
    first, later = load_script("c1723@0:4"), load_script("c1723@4.5:7")
    assert not first.shares_samples_with(later) and not later.shares_samples_with(first)
    assert first.shares_samples_with(load_script("c1723@3.9:6"))
    assert not first.shares_samples_with(load_script("rudder_kick@0:4"))
    rec = load_recording("recordings/c1723_30s.mcap")
    (tmp_path / "link.mcap").symlink_to(Path("recordings/c1723_30s.mcap").resolve())
    assert rec.shares_samples_with(load_recording(tmp_path / "link.mcap"))
    # a recording of a script's flight is told apart from the script by its origin, not
    # by comparing samples
    assert not rec.shares_samples_with(first)


def test_mavlink_log_is_resampled_at_100_hz(flight_data):
    m = load_recording(flight_data / "vtol.tlog")
    assert m.rate_hz == pytest.approx(100.0)
    assert 150.0 < m.duration_s < 260.0  # the log covers about 208 s
    # a real flight: gravity is there on average, and the vehicle moved
    assert -11.0 < float(np.median(m.specific_force[:, 2])) < -8.5
    assert float(np.ptp(m.attitude[:, 0])) > math.radians(5)


# --------------------------------------------------------------------------- the score


def test_zero_gains_leave_the_error_equal_to_the_aircrafts_perceived_motion(kick, ceart):
    geometry, reach = ceart
    params = _zero_gains(WashoutParams.preset("default"))
    problem = tuning.TuningProblem(geometry, (kick,), reach)
    run = tuning.run_chain(problem.config(params, kick), kick)
    sel = run.running
    assert sel.sum() > 400  # the soft start (2 s) is excluded, the rest is scored
    np.testing.assert_allclose(run.pose[sel], 0.0, atol=1e-12)  # no cue: the platform is still
    score = problem.evaluate(params).scores[0]
    # independent: what the pilot perceives of the aircraft alone (the platform adds nothing)
    f = perceived_specific_force(kick.specific_force[sel], kick.dt, normalized=True, g=G)
    w = perceived_angular_velocity(kick.angular_velocity[sel], kick.dt)
    np.testing.assert_allclose(score.rmse_specific_force, np.sqrt(np.mean(f**2, axis=0)))
    np.testing.assert_allclose(score.rmse_angular_velocity, np.sqrt(np.mean(w**2, axis=0)))
    assert score.clamped == 0.0 and score.limited == 0.0


def test_the_ideal_platform_scores_below_a_bad_set_and_the_default(ceart):
    """A manoeuvre a platform can fly exactly: its own motion is the aircraft's."""
    geometry, reach = ceart
    dt = 1 / 120
    t = np.arange(1, 1201) * dt
    pose = np.zeros((t.size, 6))
    pose[:, 0] = 0.05 * np.sin(1.5 * t) * np.minimum(1.0, t / 3)  # surge, m
    pose[:, 3] = np.radians(4) * np.sin(0.7 * t) * np.minimum(1.0, t / 3)  # roll
    pose[:, 4] = np.radians(3) * (1 - np.cos(0.5 * t))  # pitch
    aircraft = Manoeuvre(
        name="platform-flyable",
        source="test",
        dt=dt,
        t=t,
        specific_force=platform_specific_force(pose, dt, G),
        angular_velocity=platform_angular_velocity(pose, dt),
        attitude=pose[:, 3:],
    )
    running = np.ones(t.size, dtype=bool)
    ideal = tuning.ChainRun(pose, ~running, ~running, running, running)
    perfect = tuning.score_motion(aircraft, ideal, reach, G)
    assert perfect.error_specific_force < 1e-9 and perfect.error_angular_velocity < 1e-9
    assert perfect.false_cue_share == 0.0 and perfect.workspace_excess == 0.0
    problem = tuning.TuningProblem(geometry, (aircraft,), reach)
    default = WashoutParams.preset("default")
    bad = dataclasses.replace(default, specific_force_gain=(1, 1, 1), translational_wn=(8, 8, 8))
    scores = [problem.evaluate(p).cost for p in (default, bad, _zero_gains(default))]
    assert perfect.cost < min(scores)


def test_a_profiled_file_is_scored_with_the_manoeuvres_flight_phase(takeoff, ceart):
    """The take-off run is on the ground throughout (JSBSim's weight on wheels): a file with
    flight-phase profiles scores there exactly as its ground profile alone does (the
    compiled classical washout with the ground values), not as the file's own values."""
    geometry, reach = ceart
    assert (takeoff.on_ground == 1.0).all()
    profiled = WashoutParams.preset("profiles_example")
    ground = profiled.for_profile("ground")
    assert ground != profiled.for_profile(None)  # the profile changes something
    problem = tuning.TuningProblem(geometry, (takeoff,), reach)
    with_phase = tuning.run_chain(problem.config(profiled, takeoff), takeoff)
    alone = tuning.run_chain(problem.config(ground, takeoff), takeoff)
    base = tuning.run_chain(problem.config(profiled.for_profile(None), takeoff), takeoff)
    np.testing.assert_allclose(with_phase.angles, alone.angles, rtol=0, atol=1e-12)
    assert np.abs(base.angles - alone.angles).max() > 1e-3
    assert problem.evaluate(profiled).cost == pytest.approx(problem.evaluate(ground).cost)


def test_tuning_a_profile_changes_only_that_profile_and_scores_where_it_runs(takeoff, ceart):
    """On the take-off run (on the ground throughout): tuning the air profile cannot change
    the manoeuvre's score (that profile never runs; only its sizing counts), while tuning
    the ground profile changes only that profile's overrides, and the best set scores as
    its ground profile alone."""
    geometry, reach = ceart
    problem = tuning.TuningProblem(geometry, (takeoff,), reach)
    start = WashoutParams.preset("profiles_example")

    costs: list[float] = []

    def evaluate_many(candidates):
        scores = [problem.evaluate(p) for p in candidates]
        costs.extend(s.scores[0].cost for s in scores)
        return scores

    air = tuning.tune(start, evaluate_many, budget=7, seed=0, profile="air")
    assert len(costs) == 7 and len(set(costs)) == 1  # every candidate flew as the start
    assert air.best is air.start
    ground = tuning.tune(start, evaluate_many, budget=7, seed=0, profile="ground")
    best = ground.best
    assert best.for_profile(None) == start.for_profile(None)  # the file's own values
    assert best.for_profile("air") == start.for_profile("air")
    assert ground.best_score.cost < ground.start_score.cost  # something was found
    assert best.for_profile("ground") != start.for_profile("ground")
    alone = problem.evaluate(best.for_profile("ground"))
    assert ground.best_score.cost == pytest.approx(alone.cost)


def test_clamping_is_counted_and_costs(takeoff, ceart):
    geometry, reach = ceart
    default = WashoutParams.preset("default")
    # a forward force at full gain with a slow washout drives surge past its reach
    greedy = dataclasses.replace(
        default,
        specific_force_gain=(1, 1, 1),
        specific_force_limit=(6, 6, 6),
        translational_wn=(0.3, 0.3, 0.3),
        translational_wb=(0.05, 0.05, 0.05),
        tilt_angle_limit_deg=1.0,
    )
    problem = tuning.TuningProblem(geometry, (takeoff,), reach)
    run = tuning.run_chain(problem.config(greedy, takeoff), takeoff)
    score = problem.evaluate(greedy).scores[0]
    expected = np.mean((run.clamped | run.limited)[run.running])
    assert expected > 0.05  # it did clamp
    assert score.limited == pytest.approx(expected)
    assert score.workspace_max > 0.8  # the realised pose went to the edge of the reach
    # cranks: neutral at 0 deg, limits +-60 deg on ceart
    peak = np.max(np.abs(np.degrees(run.angles[run.running])), axis=0)
    np.testing.assert_allclose(score.crank_usage, peak / 60.0, rtol=1e-9)
    no_limits = dataclasses.replace(
        score, limited=0.0, workspace_usage=np.zeros(6), crank_usage=np.zeros(6)
    )
    assert score.cost - no_limits.cost == pytest.approx(
        tuning.WEIGHT_LIMITS * expected + tuning.WEIGHT_WORKSPACE * score.workspace_excess
    )


def _steep(default: WashoutParams) -> WashoutParams:
    """``default`` with full force gains, a 20 deg tilt limit and no rotation cue: under a
    saturated -x force it tilts the nose down to 20 deg, beyond ``ceart``'s 17.6 deg reach."""
    return dataclasses.replace(
        default,
        specific_force_gain=(1, 1, 1),
        specific_force_limit=(5, 5, 5),
        tilt_angle_limit_deg=20.0,
        angular_velocity_gain=(0, 0, 0),
    )


def test_saturated_inputs_beyond_the_reach_cost(kick, ceart):
    geometry, reach = ceart
    default = WashoutParams.preset("default")
    problem = tuning.TuningProblem(geometry, (kick,), reach)
    assert problem.evaluate(default).sizing_excess == 0.0  # the presets' rule holds
    # a saturated -x force tilts the nose down to the tilt limit (asin(K L / g) is beyond
    # it) and nothing else pitches: pitch uses 20 deg of the 17.6 deg nose-down reach
    steep = _steep(default)
    score = problem.evaluate(steep)
    pitch = score.sizing_usage[4]
    assert pitch == pytest.approx(math.radians(20.0) / -reach[0, 4], rel=1e-6)
    assert pitch > 1.0
    excess = np.maximum(0.0, score.sizing_usage - tuning.SIZING_MARGIN).sum()
    manoeuvres = np.mean([s.cost for s in score.scores])
    assert score.cost == pytest.approx(manoeuvres + tuning.WEIGHT_SIZING * excess)


def test_a_profile_beyond_the_reach_under_saturated_inputs_costs(kick, ceart):
    """The sizing rule holds for each flight-phase profile, not only for the file's own
    values: a ground profile that tilts to 20 deg under a saturated force (``_steep``) is
    sized as that set alone. It was sized by the file's own values, so
    ``tune --profile ground`` could push the profile past the rule at no cost."""
    geometry, reach = ceart
    default = WashoutParams.preset("default")
    steep = _steep(default)
    profiled = default.with_profile("ground", steep)
    assert profiled.for_profile(None) == default
    usage = tuning.saturated_reach_use(profiled, reach)
    # the nose-down tilt at its 20 deg limit, against the 17.6 deg nose-down reach
    assert usage[4] == pytest.approx(math.radians(20.0) / -reach[0, 4], rel=1e-6)
    problem = tuning.TuningProblem(geometry, (kick,), reach)
    assert problem.evaluate(profiled).sizing_excess > 0.2


def test_the_tables_mean_row_is_the_mean_of_its_rows(kick, takeoff, ceart):
    """The "mean of N" row's cost is the mean of the manoeuvres' costs printed above it; the
    sizing term (which no manoeuvre has) is printed apart, with the score it makes. The
    mean row showed the score, so a set beyond the sizing rule had a "mean" several times
    its rows' costs."""
    geometry, reach = ceart
    default = WashoutParams.preset("default")
    steep = dataclasses.replace(
        default, specific_force_gain=(1, 1, 1), specific_force_limit=(5, 5, 5),
        tilt_angle_limit_deg=20.0,
    )  # fmt: skip
    problem = tuning.TuningProblem(geometry, (kick, takeoff), reach)
    before, after = problem.evaluate(default), problem.evaluate(steep)
    assert after.sizing_excess > 0.5
    lines = tuning.format_table([("tuning set", before, after)]).splitlines()
    rows = [line.split() for line in lines if line.startswith(("  rudder_kick", "  c1723"))]
    mean = next(line.split() for line in lines if line.startswith("  mean of 2"))
    for col in (-2, -1):  # cost before, after
        assert float(mean[col]) == pytest.approx(np.mean([float(r[col]) for r in rows]), abs=2e-3)
    score = lines[-1]
    assert score.startswith("score tuned") and score.endswith(
        f"{before.cost:.3f} -> {after.cost:.3f}"
    )
    assert after.cost == pytest.approx(float(mean[-1]) + 10 * after.sizing_excess, abs=1e-3)


def test_shipped_tuned_ceart_preset(ceart):
    """``--washout tuned_ceart``: made by the tuner, fits the presets' rule, and beats the
    default on the default manoeuvres without clamping more (rerun the command in its header
    when the geometry or the default changes and this fails)."""
    geometry, reach = ceart
    tuned = WashoutParams.preset("tuned_ceart")
    text = preset_path("washout", "tuned_ceart").read_text()
    assert "# motionbase tune --platform ceart --washout default" in text
    assert (tuning.saturated_reach_use(tuned, reach) <= tuning.SIZING_MARGIN).all()
    problem = tuning.TuningProblem(
        geometry, tuple(load_script(s) for s in DEFAULT_MANOEUVRES), reach
    )
    default, after = problem.evaluate(WashoutParams.preset("default")), problem.evaluate(tuned)
    assert after.cost < default.cost
    assert after.error_specific_force < default.error_specific_force
    assert after.limited <= default.limited


def test_shipped_tuned_seat_preset():
    """``--params tuned_seat``, the Stewart platform's default: made by the tuner for it, fits
    the presets' rule on its reach (the SIMONA set does not: 97 % of it), and beats that set
    on the default manoeuvres without clamping more."""
    geometry = Stewart6Geometry.preset("seat")
    reach = robot_reach(Stewart6Robot(geometry))
    tuned, simona = WashoutParams.preset("tuned_seat"), WashoutParams.preset("default")
    text = preset_path("washout", "tuned_seat").read_text()
    assert "# motionbase tune --platform stewart6 --washout default" in text
    assert (tuning.saturated_reach_use(tuned, reach) <= tuning.SIZING_MARGIN).all()
    assert (tuning.saturated_reach_use(simona, reach) > tuning.SIZING_MARGIN).any()
    problem = tuning.TuningProblem(
        geometry, tuple(load_script(s) for s in DEFAULT_MANOEUVRES), reach, robot="stewart6"
    )
    default, after = problem.evaluate(simona), problem.evaluate(tuned)
    assert after.cost < default.cost
    assert after.error_specific_force < default.error_specific_force
    assert after.limited <= default.limited


def test_encode_decode_round_trip_and_bounds():
    default = WashoutParams.preset("default")
    x = tuning.encode(default)
    assert x.shape == (len(tuning.KNOBS),) and ((x >= 0) & (x <= 1)).all()
    assert tuning.decode(x, default) == default  # its values have 4 digits or fewer
    low = tuning.decode(np.zeros(len(tuning.KNOBS)), default)
    high = tuning.decode(np.ones(len(tuning.KNOBS)) * 2.0, default)  # clipped to 1
    for k in tuning.KNOBS:
        assert k.get(low) == pytest.approx(k.lo) and k.get(high) == pytest.approx(k.hi)
    assert high.translational_wb[0] == high.translational_wb[1]  # one knob for x and y
    assert low.translational_zeta == default.translational_zeta  # not tuned: kept


@pytest.mark.parametrize(
    "param", ["tilt_rate_limit_deg_s", "tilt_angle_limit_deg", "tilt_accel_limit_deg_s2"]
)
def test_the_tuner_sets_roll_and_pitch_tilt_limits_apart(param):
    """A tilt limit is one number or [roll, pitch] in a washout file; the tuner has a knob
    for each axis, so moving one leaves the other as it was."""
    default = WashoutParams.preset("default")
    x = tuning.encode(default)
    knobs = [i for i, k in enumerate(tuning.KNOBS) if k.param == param]
    assert [tuning.KNOBS[i].axes for i in knobs] == [(0,), (1,)]
    roll, pitch = knobs
    for moved, kept in ((roll, 1), (pitch, 0)):
        y = x.copy()
        y[moved] = 1.0 - y[moved]
        values = getattr(tuning.decode(y, default), param)
        assert values[kept] == getattr(default, param)[kept]
        assert values[1 - kept] != getattr(default, param)[1 - kept]
        # and the file the tuner writes says both
        key = param.removeprefix("tilt_")
        assert tuning.decode(y, default).to_dict()["tilt"][key] == list(values)


# --------------------------------------------------------------------------- the optimiser


def _bad_start() -> WashoutParams:
    """A greedy washout: full gains and slow high-passes, so the platform drifts to its
    limits (clamping) and cues rotations it never washes out."""
    return dataclasses.replace(
        WashoutParams.preset("default"),
        specific_force_gain=(1, 1, 1),
        angular_velocity_gain=(1, 1, 1),
        translational_wn=(0.3, 0.3, 0.3),
        translational_wb=(0.05, 0.05, 0.05),
        rotational_wn=(0.2, 0.2, 0.2),
    )


def test_the_optimiser_improves_a_bad_start(kick, ceart):
    geometry, reach = ceart
    problem = tuning.TuningProblem(geometry, (kick,), reach)
    seen = []
    result = tuning.tune(
        _bad_start(),
        lambda ps: [problem.evaluate(p) for p in ps],
        budget=25,
        seed=4,
        on_progress=lambda done, budget, best: seen.append((done, best)),
    )
    assert result.evaluations == 25
    assert [d for d, _ in seen][-1] == 25 and seen[0][0] == 1
    assert all(b2 <= b1 for (_, b1), (_, b2) in zip(seen, seen[1:], strict=False))
    start, best = result.start_score, result.best_score
    assert start.limited > 0.1  # the start clamps: it is bad
    assert best.cost < 0.7 * start.cost
    assert best.limited < start.limited
    # what was reported is what the parameters score
    assert problem.evaluate(result.best).cost == best.cost


def test_same_seed_same_result_other_seed_other_path(kick, ceart):
    geometry, reach = ceart
    problem = tuning.TuningProblem(geometry, (kick,), reach)

    def run(seed):
        return tuning.tune(
            _bad_start(), lambda ps: [problem.evaluate(p) for p in ps], budget=9, seed=seed
        )

    a, b, c = run(7), run(7), run(8)
    assert a.best == b.best and a.history == b.history
    assert c.history != a.history


class _EvaluationClock:
    """Time that passes only while parameter sets are scored: ``cost_s`` per set."""

    def __init__(self, problem, cost_s: float) -> None:
        self.now, self.problem, self.cost_s = 0.0, problem, cost_s

    def __call__(self) -> float:
        return self.now

    def evaluate_many(self, candidates):
        self.now += self.cost_s * len(candidates)
        return [self.problem.evaluate(p) for p in candidates]


def test_a_time_budget_starts_no_generation_that_would_end_after_it(kick, ceart):
    """Each set scored takes 1 s (of a test's clock): with 30 s, the start (1 s) and two
    generations of 13 (to 27 s) fit; a third would end at 40 s, so it does not start."""
    geometry, reach = ceart
    problem = tuning.TuningProblem(geometry, (kick,), reach)
    popsize = 4 + int(3 * math.log(len(tuning.KNOBS)))  # CMA-ES's default population
    clock = _EvaluationClock(problem, 1.0)
    timed = tuning.tune(
        _bad_start(), clock.evaluate_many, budget=None, seed=4, time_budget_s=30.0, clock=clock
    )
    assert timed.ended_by == "time" and clock.now <= 30.0
    assert timed.generations == 2 and timed.evaluations == 1 + 2 * popsize == clock.now
    # the same seed with an evaluation budget of those 27: the same search, ended by it
    counted = tuning.tune(
        _bad_start(), _EvaluationClock(problem, 1.0).evaluate_many, budget=27, seed=4
    )
    assert counted.ended_by == "budget" and counted.history == timed.history
    assert counted.best == timed.best
    # both budgets: the sooner ends it
    both = _EvaluationClock(problem, 1.0)
    sooner = tuning.tune(
        _bad_start(), both.evaluate_many, budget=14, seed=4, time_budget_s=30.0, clock=both
    )
    assert sooner.ended_by == "budget" and sooner.evaluations == 14
    with pytest.raises(ValueError, match="budget of evaluations, of time, or both"):
        tuning.tune(_bad_start(), both.evaluate_many, budget=None, seed=4)


def test_tune_with_only_a_time_budget_says_so_in_its_file(tmp_path):
    """``--time-budget`` alone: no limit on evaluations; the time ends the tuning, and the
    file's header says so and how to run it again."""
    out = tmp_path / "timed.toml"
    res = app.tune(
        out=out, washout="default", scripts=["rudder_kick@0:6"], holdout=[], workers=1,
        time_budget_s=4.0, progress=False,
    )  # fmt: skip
    assert res.result.ended_by == "time" and res.result.evaluations > 1
    assert "ended by the time budget (4s)" in res.summary_text().splitlines()[0]
    head = out.read_text().splitlines()
    assert "--holdout none --time-budget 4s --seed 0 --out timed.toml" in head[1]
    assert "--budget" not in head[1]
    assert head[2].startswith(
        f"# The time budget (4s) ended the tuning after {res.result.evaluations}"
    )
    assert WashoutParams.from_toml(out) == res.result.best


@pytest.mark.parametrize(
    ("text", "seconds"), [("90", 90.0), ("90s", 90.0), ("30m", 1800.0), ("1.5h", 5400.0)]
)
def test_time_budget_durations(text, seconds):
    args = cli.build_parser().parse_args(["tune", "--time-budget", text, "--out", "o.toml"])
    assert args.time_budget == seconds and args.budget is None
    assert app.duration_text(seconds) == {"90": "90s", "1.5h": "90m"}.get(text, text)


# --------------------------------------------------------------------------- the job and its file


def test_tune_writes_a_washout_file_that_loads_and_flies(tmp_path, capsys):
    out = tmp_path / "new" / "tuned.toml"  # its folder is made, as fly --out makes one
    code = cli.main(
        [
            "tune",
            "--scripts",
            "rudder_kick@0:5",
            "--holdout",
            "c172_cross_wind@0.5:5",
            "--budget",
            "4",
            "--seed",
            "1",
            "--workers",
            "1",
            "--out",
            str(out),
        ]
    )
    text = capsys.readouterr().out
    assert code == 0
    assert "tuning set" in text and "held out" in text and "c172_cross_wind@0.5:5" in text
    assert "  mean of 1 (workspace: largest)" in text  # that column is no mean
    head = out.read_text().splitlines()[0]
    assert head.startswith("# Washout parameters made by `motionbase tune`")
    params = WashoutParams.from_toml(out)
    assert params.description.startswith("Tuned by motionbase tune")
    result = app.fly(
        "c172_elevator_doublet", washout=str(out), duration_s=4.0, out=tmp_path / "f.mcap"
    )
    assert not result.failed and result.summary.samples > 400


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_reaches_a_log_file_now_and_then_and_a_terminal_in_place():
    """Off a terminal (CI, a journal) a long tuning run prints a whole line every so often,
    a short one nothing; on a terminal the line is redrawn in place and ended once."""
    log = io.StringIO()
    every = app.EvaluationProgress(log, every_s=0.0)
    every(1, 10, 5.0)
    every(6, 10, 4.0)
    every.close()
    lines = log.getvalue().splitlines()
    assert "\r" not in log.getvalue() and len(lines) == 2
    assert lines[1].startswith("tune: 6 / 10 evaluations  best 4.0000 (start 5.0000), ")
    short = io.StringIO()
    rare = app.EvaluationProgress(short, every_s=3600.0)
    rare(1, 10, 5.0)
    rare.close()
    assert short.getvalue() == ""
    tty = _Terminal()
    bar = app.EvaluationProgress(tty, every_s=3600.0)
    bar(1, 10, 5.0)
    bar(10, 10, 4.0)
    bar.close()
    text = tty.getvalue()
    assert text.count("\r") == 2 and text.endswith("\n") and text.count("\n") == 1
    assert "10 / 10 evaluations" in text.rsplit("\r", 1)[1]
    # a time budget alone: no count to reach; the time to go is the time left
    timed_log = io.StringIO()
    timed = app.EvaluationProgress(timed_log, every_s=0.0, time_budget_s=3600.0)
    timed(3, None, 5.0)
    timed.close()
    line = timed_log.getvalue().strip()
    assert re.fullmatch(r"tune: 3 evaluations  best 5\.0000 \(start 5\.0000\), +\d+ s, "
                        r"about 3[56]\d\d s to go", line), line  # fmt: skip


def test_tune_result_in_the_file_is_the_best_scored(tmp_path, kick, ceart):
    out = tmp_path / "t.toml"
    res = app.tune(out=out, scripts=["rudder_kick@0:6"], holdout=[], budget=6, seed=2, workers=1)
    assert res.holdout is None
    loaded = WashoutParams.from_toml(out)
    assert loaded == res.result.best
    geometry, reach = ceart
    again = tuning.TuningProblem(geometry, (kick,), reach).evaluate(loaded)
    assert again.cost == res.result.best_score.cost


def test_tune_takes_a_stewart_platform(tmp_path, kick):
    out = tmp_path / "s.toml"
    res = app.tune(
        out=out, platform="stewart6", scripts=["rudder_kick@0:6"], holdout=[], budget=4, workers=1
    )
    assert "--platform stewart6" in out.read_text().splitlines()[1]
    geometry = Stewart6Geometry.preset("seat")
    problem = tuning.TuningProblem(
        geometry, (kick,), robot_reach(Stewart6Robot(geometry)), robot="stewart6"
    )
    # the legs, from the preset's numbers: 0.75 m at neutral, 0.60-0.90 m
    np.testing.assert_allclose(problem.cranks, [[0.75] * 6, [0.60] * 6, [0.90] * 6], atol=1e-12)
    assert problem.evaluate(res.result.best).cost == res.result.best_score.cost
    # the scored actuator use: the legs' largest excursion from 0.75 m, over the 0.15 m stroke
    run = tuning.run_chain(problem.config(res.result.best, kick), kick)
    legs = run.angles[run.running]
    assert np.all((legs > 0.60) & (legs < 0.90))
    expected = np.maximum((legs.max(axis=0) - 0.75) / 0.15, (0.75 - legs.min(axis=0)) / 0.15)
    score = problem.evaluate(res.result.best).scores[0]
    np.testing.assert_allclose(score.crank_usage, expected, rtol=1e-12)
    assert 0.0 < score.crank_usage.max() < 1.0
    flown = app.fly(
        "c172_elevator_doublet",
        platform="stewart6",
        washout=str(out),
        duration_s=3.0,
        out=tmp_path / "f.mcap",
    )
    assert not flown.failed and flown.summary.samples > 300


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["--cueing", "fancy"], "invalid choice"),
        (["--out", "x.txt"], "name it *.toml"),
        (["--out", "/dev/null/o.toml"], "/dev/null is not a folder"),  # before the tuning
        (["--scripts", "no_such_script"], "unknown JSBSim script"),
        (["--scripts", "c1721@20:30"], "the script is shorter"),
        # a window shorter than three samples was said to lie past the script's end
        (["--scripts", "c1723@0:0.001"], "choose a longer window"),
        (["--scripts", "c1723@5:x"], "two numbers"),
        (["--scripts", "c1723@0:5", "--holdout", "c1723@0:5"], "also in the tuning set"),
        # the same samples under another name, or windows of one flight that overlap: the
        # held-out table scored the tuning set's own samples as "not tuned on"
        (["--scripts", "c1723@0:5", "--holdout", "c1723@0:5.0"], "also in the tuning set"),
        (["--scripts", "c1723@0:5", "--holdout", "c1723@4:9"], "the same flight's samples"),
        (["--scheduler", "localhost:8786"], "tcp://HOST:PORT"),
        # a port no scheduler can have waited out the connection timeout, then said that
        # no scheduler answers there
        (["--scheduler", "tcp://127.0.0.1:0"], "port 0 is out of range (1..65535)"),
        (["--scheduler", "tcp://127.0.0.1:99999"], "port 99999 is out of range (1..65535)"),
        (["--budget", "0"], "expected a whole number >= 1"),
        (["--time-budget", "soon"], "expected a duration such as 90s, 30m or 8h"),
        (["--time-budget", "0s"], "expected a duration such as 90s, 30m or 8h"),
        (["--recordings", "notes.txt"], "MCAP file"),
        (["--profile", "taxi"], "--profile taxi: unknown"),
        (["--cueing", "mpc", "--profile", "air"], "no flight-phase profiles"),
        (["--preview"], "--preview: the classical cueing does not use the flight's future"),
        (["--platform", "rrr3"], "tune scores 6-DOF platforms"),
        (["--platform", "udesc"], "tune scores 6-DOF platforms"),  # a 3-RRR preset
        (["--seed", "4294967295"], "--seed must be a whole number from 0 to 4294967294"),
        (["--workers", "1000"], "--workers 1000: this process may use"),
        # checked before the manoeuvres are flown (it came after them, and after their errors)
        (["--scripts", "no_such_script", "--workers", "1000"], "--workers 1000: this process"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(argv, needle, tmp_path, capsys):
    args = ["tune", "--scripts", "c1723@0:5", "--holdout", "none", "--budget", "2"]
    workers = [] if "--scheduler" in argv else ["--workers", "1"]  # (not both: refused)
    args += [*workers, "--out", str(tmp_path / "o.toml"), *argv]
    try:
        code = cli.main(args)
    except SystemExit as exc:  # argparse's own errors exit through SystemExit
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2
    assert needle in err and len(err.strip().splitlines()) == 1, err
    if "name it" not in needle:
        assert not (tmp_path / "o.toml").exists() or needle == "MCAP file"


# --------------------------------------------------------------------------- where it runs


def test_process_pool_and_dask_cluster_give_the_same_scores(kick, ceart):
    import distributed  # (the test extra installs it: missing, the test fails, not skips)

    geometry, reach = ceart
    problem = tuning.TuningProblem(geometry, (kick,), reach)
    default = WashoutParams.preset("default")
    candidates = [default, _bad_start(), tuning.decode(np.full(len(tuning.KNOBS), 0.3), default)]
    here = [problem.evaluate(p) for p in candidates]
    with open_evaluator(problem, workers=2) as evaluate_many:
        pooled = evaluate_many(candidates)
    with distributed.LocalCluster(
        n_workers=1,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address=None,
    ) as cluster:
        assert cluster.scheduler_address.startswith("tcp://127.0.0.1:")
        with open_evaluator(problem, scheduler=cluster.scheduler_address) as evaluate_many:
            remote = evaluate_many(candidates)
    for a, b, c in zip(here, pooled, remote, strict=True):
        assert a.cost == b.cost == c.cost
        np.testing.assert_array_equal(
            a.scores[0].rmse_specific_force, c.scores[0].rmse_specific_force
        )
    assert len({s.cost for s in here}) == 3  # three different sets, three different scores


@contextlib.contextmanager
def _dask_scheduler(tmp_path: Path) -> Iterator[tuple[subprocess.Popen, str]]:
    """A Dask scheduler in a process of its own, on loopback: the process and its address."""
    file = tmp_path / "scheduler.json"
    proc = subprocess.Popen(
        [sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
         "--port", "0", "--no-dashboard", "--scheduler-file", str(file)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 60
        while proc.poll() is None and time.monotonic() < deadline:
            try:
                address = json.loads(file.read_text())["address"]
                break
            except (OSError, ValueError, KeyError):  # not written yet, or not whole
                time.sleep(0.1)
        else:
            raise AssertionError("the Dask scheduler did not start")
        yield proc, address
    finally:
        proc.kill()
        proc.wait()


def _dask_worker(address: str, site: Path | None = None) -> subprocess.Popen:
    """A Dask worker process (no nanny: killing it kills the worker), registered with the
    scheduler at ``address``; ``site``: a folder put first on its PYTHONPATH (a
    ``sitecustomize.py`` there changes the machine it stands for)."""
    env = dict(os.environ)
    if site is not None:
        env["PYTHONPATH"] = os.pathsep.join([str(site), env.get("PYTHONPATH", "")])
    proc = subprocess.Popen(
        [sys.executable, "-m", "distributed.cli.dask_worker", address, "--nthreads", "1",
         "--no-nanny", "--no-dashboard"],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    import distributed

    with distributed.Client(address, timeout=30, set_as_default=False) as client:
        client.wait_for_workers(1, timeout=60)
    return proc


#: ``sitecustomize.py`` of a worker's machine: without motionbase, with another version.
_WORKER_MACHINES = {
    "cannot run motionbase (ModuleNotFoundError": """
import sys
class NoMotionbase:
    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] == "motionbase":
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
sys.meta_path.insert(0, NoMotionbase())
""",
    "runs motionbase 0.0.1, this is motionbase": """
import motionbase
motionbase.__version__ = "0.0.1"
""",
}


def test_a_cluster_that_cannot_run_the_tuning_is_one_line_and_exit_2(tmp_path, capsys):
    """A scheduler without workers, a worker without motionbase, one with another version:
    one line each, exit 2, before anything is evaluated. (The first was a TimeoutError
    traceback, ten seconds on; the second a traceback from the problem's scatter; the
    third was not checked.)"""
    args = ["tune", "--scripts", "rudder_kick@0:2", "--holdout", "none", "--budget", "2",
            "--out", str(tmp_path / "o.toml"), "--scheduler"]  # fmt: skip
    with _dask_scheduler(tmp_path) as (_, address):
        assert cli.main([*args, address]) == 2
        err = capsys.readouterr().err
        assert err.strip() == (
            f"motionbase tune: error: --scheduler {address}: the scheduler has no workers; "
            f"start them (dask worker {address}) on machines with motionbase installed"
        )
        for needle, site in _WORKER_MACHINES.items():
            machine = tmp_path / needle.split()[0]
            machine.mkdir()
            (machine / "sitecustomize.py").write_text(site)
            worker = _dask_worker(address, machine)
            try:
                assert cli.main([*args, address]) == 2
            finally:
                worker.kill()
                worker.wait()
            err = capsys.readouterr().err
            assert needle in err and len(err.strip().splitlines()) == 1, err[-2000:]
            assert "install this version on every machine" in err
    assert not (tmp_path / "o.toml").exists()


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads processor time from /proc")
@pytest.mark.parametrize("lost", ["scheduler", "worker"])
def test_a_cluster_lost_while_tuning_is_one_line_and_exit_2(lost, tmp_path):
    """The scheduler, or its only worker (the problem scattered to it with it), goes away
    while ``tune`` evaluates: one line, exit 2, nothing written. (It was a CancelledError
    traceback, or, when the scheduler went after a task had finished and before its result
    came back, a wait that never ended.)"""
    out = tmp_path / "o.toml"
    args = ["tune", "--scripts", "rudder_kick@0:6", "--holdout", "none", "--budget",
            "100000", "--out", str(out)]  # fmt: skip
    with _dask_scheduler(tmp_path) as (scheduler, address):
        worker = _dask_worker(address)
        try:
            started = _cpu_seconds(worker.pid)
            proc = subprocess.Popen(
                [sys.executable, "-m", "motionbase.cli", *args, "--scheduler", address],
                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
            )  # fmt: skip
            deadline = time.monotonic() + 60  # evaluations under way: the worker computes
            while _cpu_seconds(worker.pid) < started + 2.0 and time.monotonic() < deadline:
                time.sleep(0.1)
            (scheduler if lost == "scheduler" else worker).kill()
            try:
                _, err = proc.communicate(timeout=60)
            finally:
                proc.kill()
        finally:
            worker.kill()
            worker.wait()
    assert err.decode().strip() == (
        f"motionbase tune: error: --scheduler {address}: the cluster lost the evaluations "
        "(the scheduler or all its workers went away); nothing was written; run again once "
        "the scheduler and its workers are back"
    )
    assert proc.returncode == 2
    assert not out.exists()


@pytest.fixture
def silent_peer() -> Iterator[tuple[str, threading.Event]]:
    """A loopback port that takes connections and never says a word (another program on
    the scheduler's port): its address, and an event set once something connects."""
    server = socket.create_server(("127.0.0.1", 0))
    taken: list[socket.socket] = []
    connected = threading.Event()

    def serve() -> None:
        while True:
            try:
                taken.append(server.accept()[0])
            except OSError:  # closed
                return
            connected.set()

    threading.Thread(target=serve, daemon=True).start()
    yield f"tcp://127.0.0.1:{server.getsockname()[1]}", connected
    server.shutdown(socket.SHUT_RDWR)
    server.close()
    for conn in taken:
        conn.close()


def test_a_scheduler_address_where_nothing_answers_is_one_line_and_exit_2(silent_peer, tmp_path):
    """A port that takes the connection and says nothing: Dask's client waited for it
    forever, and Ctrl-C did not end the wait. Now the connection's timeout ends it."""
    address, _ = silent_peer
    proc = subprocess.run(
        [sys.executable, "-m", "motionbase.cli", "tune", "--scripts", "rudder_kick@0:2",
         "--holdout", "none", "--budget", "2", "--out", str(tmp_path / "o.toml"),
         "--scheduler", address],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert proc.returncode == 2
    assert proc.stderr.strip() == (
        f"motionbase tune: error: --scheduler {address}: no Dask scheduler answers there "
        "(no answer within 11 s); start one (dask scheduler) or check the address and the "
        "firewall"
    )
    assert not (tmp_path / "o.toml").exists()


def test_a_signal_while_tune_connects_to_the_scheduler_ends_it(silent_peer, tmp_path):
    """Ctrl-C while the client waits for the scheduler's answer: one line, exit 130, at
    once. (The signal was held until the connection's timeout, then the run said that no
    scheduler answers, exit 2; with a peer that says nothing, it was not ended at all.)"""
    address, connected = silent_peer
    args = ["tune", "--scripts", "rudder_kick@0:2", "--holdout", "none", "--budget", "2",
            "--out", str(tmp_path / "o.toml"), "--scheduler", address]  # fmt: skip
    status, err = signalled(args, lambda _: connected.wait(60))
    assert err.strip() == "motionbase tune: interrupted"
    assert status == 130
    assert not (tmp_path / "o.toml").exists()


@pytest.mark.parametrize("workers", [1, 2])
def test_a_stop_cancels_the_evaluations_not_yet_started(workers, kick, ceart):
    """A stop request set while a batch of evaluations runs ends it with ``Stopped``
    instead of letting it finish (400 evaluations of the kick: several seconds)."""
    geometry, reach = ceart
    problem = tuning.TuningProblem(geometry, (kick,), reach)
    default = WashoutParams.preset("default")
    stop = StopRequest()
    with open_evaluator(problem, workers=workers, stop=stop) as evaluate_many:
        assert len(evaluate_many([default, _bad_start()])) == 2  # no stop: they run
        timer = threading.Timer(0.3, stop.set, args=("SIGTERM",))
        timer.start()
        with pytest.raises(Stopped) as stopped:
            evaluate_many([default] * 400)
        timer.join()
        with pytest.raises(Stopped):  # and stays stopped
            evaluate_many([default])
    assert stopped.value.reason == "SIGTERM"
    assert stopped.value.exit_status == 128 + signal.SIGTERM


def test_a_stopped_tuning_hands_back_the_best_set_of_the_batches_it_finished(kick, ceart):
    """A stop during the third batch of CMA-ES candidates: :func:`tuning.tune` raises
    ``TuningStopped`` carrying the best of the start and the two batches whose scores came
    back (the third is lost), counted as such."""
    geometry, reach = ceart
    problem = tuning.TuningProblem(geometry, (kick,), reach)
    stop = StopRequest()
    seen: list[tuple[WashoutParams, float]] = []  # every set scored, and its cost
    batches = 0
    with open_evaluator(problem, workers=1, stop=stop) as evaluate_many:

        def evaluate_until_the_third_batch(candidates):
            nonlocal batches
            batches += 1
            if batches == 4:  # the start, two generations, then Ctrl-C
                stop.set("SIGINT")
            scores = evaluate_many(candidates)
            seen.extend((c, s.cost) for c, s in zip(candidates, scores, strict=True))
            return scores

        with pytest.raises(tuning.TuningStopped) as stopped:
            tuning.tune(_bad_start(), evaluate_until_the_third_batch, budget=200, seed=3)
    found = stopped.value.found
    assert stopped.value.reason == "SIGINT" and stopped.value.exit_status == 130
    assert batches == 4 and found.generations == 2
    popsize = 4 + int(3 * math.log(len(tuning.KNOBS)))  # CMA-ES's default population
    assert found.evaluations == len(seen) == 1 + 2 * popsize
    best_params, best_cost = min(seen, key=lambda pair: pair[1])
    assert found.best_score.cost == best_cost < found.start_score.cost == seen[0][1]
    assert found.best == best_params
    assert problem.evaluate(found.best).cost == best_cost  # the set handed back is that one


def _cpu_seconds(pid: int) -> float:
    """Processor time (user and system) a process has used so far, s; 0 once it is gone."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _workers_of(pid: int) -> list[int]:
    """Pool workers (``spawn_main`` processes) whose parent is ``pid``, from /proc."""
    out = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            cmd = (entry / "cmdline").read_bytes()
        except OSError:
            continue
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        if ppid == pid and b"spawn_main" in cmd:
            out.append(int(entry.name))
    return out


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"  # a zombie has exited


def _assert_gone(workers: list[int]) -> None:
    """Every pid of ``workers`` exits within 15 s."""
    deadline = time.monotonic() + 15
    while any(_alive(w) for w in workers) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not any(_alive(w) for w in workers), "a worker outlived motionbase tune"


def _tune_args(tmp_path: Path) -> list[str]:
    """A tuning that would run for hours: it only ends when stopped."""
    return ["tune", "--scripts", "c1723@0:20", "--holdout", "none", "--budget", "100000",
            "--workers", "2", "--out", str(tmp_path / "o.toml")]  # fmt: skip


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads workers from /proc")
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_stopping_tune_leaves_no_worker_behind(sig, tmp_path):
    workers: list[int] = []

    def evaluating(proc) -> None:
        deadline = time.monotonic() + 60
        while len(workers) < 2 and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.2)
            workers[:] = _workers_of(proc.pid)
        assert len(workers) == 2, "the pool did not start"
        time.sleep(1.0)  # evaluations under way

    status, err = signalled(_tune_args(tmp_path), evaluating, sig)
    _assert_gone(workers)
    said = "" if sig == signal.SIGINT else f" ({sig.name})"
    assert err.strip() == f"motionbase tune: interrupted{said}"
    assert status == 128 + sig, err[-2000:]
    assert not (tmp_path / "o.toml").exists()


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads workers from /proc")
def test_a_stop_does_not_wait_for_the_evaluation_under_way(tmp_path):
    """An evaluation can take minutes (here the MPC with a 5 s horizon of 100 steps, in
    preview mode: several minutes of processor time for the start set alone; the first
    evaluation after installing compiles the pipeline for up to a minute). A stop kills the
    workers instead of waiting for it: the run ends within ``signalled``'s minute, nothing
    written, no worker left. (It used to wait for the evaluation to end.)"""
    text = (preset_path("mpc", "preview_ceart")).read_text()
    text = text.replace("steps = 25", "steps = 100").replace("step_s = 0.1", "step_s = 0.05")
    start = tmp_path / "long_horizon.toml"
    start.write_text(text)
    out = tmp_path / "o.toml"
    args = ["tune", "--cueing", "mpc", "--preview", "--params", str(start), "--scripts",
            "c1723@0:40", "--holdout", "none", "--budget", "10", "--workers", "2",
            "--out", str(out)]  # fmt: skip
    workers: list[int] = []

    def evaluating(proc) -> None:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            workers[:] = _workers_of(proc.pid)
            if sum(_cpu_seconds(w) for w in workers) >= 5.0:
                return
            time.sleep(0.2)
        raise AssertionError("the workers did not start evaluating")

    status, err = signalled(args, evaluating, signal.SIGINT)
    assert err.strip() == "motionbase tune: interrupted", err[-2000:]
    assert status == 128 + signal.SIGINT
    assert not out.exists()
    _assert_gone(workers)


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads workers from /proc")
def test_a_stopped_tune_keeps_the_best_set_it_found(tmp_path):
    """SIGTERM seconds into a tuning of the SIMONA set (which CMA-ES soon beats on the
    rudder kick): the best set so far is written, its header saying so, and the one line
    on stderr names the file. The file is a washout that scores what it claims."""
    out = tmp_path / "kept.toml"
    args = ["tune", "--washout", "default", "--scripts", "rudder_kick@0:6", "--holdout",
            "none", "--budget", "100000", "--workers", "2", "--out", str(out)]  # fmt: skip

    def evaluating(proc) -> None:
        # a few hundred evaluations: 8 s of the workers' processor time, not of the clock,
        # so that a busy machine (another test beside this one) does not stop it too soon
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            if sum(_cpu_seconds(w) for w in _workers_of(proc.pid)) >= 8.0:
                return
            time.sleep(0.2)

    status, err = signalled(args, evaluating, signal.SIGTERM)
    assert status == 128 + signal.SIGTERM, err[-2000:]
    match = re.fullmatch(
        r"motionbase tune: interrupted \(SIGTERM\); kept the best set of (\d+) evaluations "
        r"in (.+) \(cost ([0-9.]+) -> ([0-9.]+)\)",
        err.strip(),
    )
    assert match, err[-2000:]
    n, path, before, after = match.groups()
    assert Path(path) == out and float(after) < float(before)
    text = out.read_text()
    assert f"# Interrupted (SIGTERM) after {n} of 100000 evaluations: the best set so far" in text
    assert not list(tmp_path.glob(".*.part"))  # written whole, nothing left beside it
    kept = WashoutParams.load(out)
    problem = tuning.TuningProblem(
        Rus6Geometry.preset("ceart"), (load_script("rudder_kick@0:6"),),
        rus6_reach(Rus6Geometry.preset("ceart")),
    )  # fmt: skip
    assert problem.evaluate(kept).cost == pytest.approx(float(after), rel=1e-3)
    assert problem.evaluate(WashoutParams.preset("default")).cost == pytest.approx(
        float(before), rel=1e-3
    )


@pytest.mark.parametrize("after_s", [0.5, 1.5, 3.0])
def test_a_signal_while_tune_starts_ends_it_cleanly(after_s, tmp_path):
    """Ctrl-C while the program loads (numba, CMA-ES and its plotting library), flies the
    JSBSim manoeuvres or starts its workers: one line, exit 130, nothing written. (A
    Ctrl-C inside an import used to surface as another library's RuntimeError.)"""
    status, err = signalled(_tune_args(tmp_path), lambda _: time.sleep(after_s))
    assert err.strip() == "motionbase tune: interrupted"
    assert status == 130
    assert not (tmp_path / "o.toml").exists()


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads workers from /proc")
@pytest.mark.parametrize(
    ("after_s", "sig"),
    [(1.5, signal.SIGTERM), (None, signal.SIGTERM), (None, signal.SIGHUP), (None, signal.SIGQUIT)],
)
def test_a_sigterm_to_the_whole_process_group_ends_tune_cleanly(after_s, sig, tmp_path):
    """``timeout`` and service managers signal the whole process group (a closed terminal
    sends SIGHUP to it), the workers too, while they start or while they evaluate (None:
    once both are running): one line, exit 128 + the signal, nothing written, no worker
    left. (A worker killed while it started used to surface as a BrokenProcessPool
    traceback; a SIGHUP or SIGQUIT killed multiprocessing's resource tracker, whose
    tracebacks followed the line.)"""
    workers: list[int] = []

    def ready(proc) -> None:
        if after_s is not None:
            time.sleep(after_s)
            return
        deadline = time.monotonic() + 60
        while len(workers) < 2 and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.2)
            workers[:] = _workers_of(proc.pid)
        assert len(workers) == 2, "the pool did not start"

    status, err = signalled(_tune_args(tmp_path), ready, sig, group=True)
    assert err.strip() == f"motionbase tune: interrupted ({sig.name})", err[-2000:]
    assert status == 128 + sig
    assert not (tmp_path / "o.toml").exists()
    _assert_gone(workers)


def test_the_ceart_default_is_the_washout_tuned_for_it(tmp_path):
    """Issue 15: the shipped default on `ceart` is the tuned set (on the Stewart platform's
    `seat`, the set tuned for it); every other geometry, and an explicit ``--params``, keep
    theirs."""
    tuned = WashoutParams.preset("tuned_ceart").to_dict()
    simona = WashoutParams.preset("default").to_dict()
    assert tuned != simona

    def params(**kwargs) -> dict:
        return app.load_config(**kwargs).cueing_params.to_dict()

    for platform in (None, "rus6", "ceart"):
        assert params(platform=platform) == tuned, platform
    # the same geometry from the user's own file, under another name: tuned too
    text = preset_path("rus6", "ceart").read_text()
    mine = tmp_path / "my_seat.toml"
    mine.write_text(text.replace('name = "ceart"', 'name = "my seat"'))
    assert params(platform=str(mine)) == tuned
    # another geometry (longer rods), another robot, the planar robot: the SIMONA set
    longer = tmp_path / "longer.toml"
    longer.write_text(text.replace("rod = 0.724", "rod = 0.760"))
    assert params(platform=str(longer)) == simona
    assert params(platform="stewart6") == WashoutParams.preset("tuned_seat").to_dict()
    assert params(planar=True) == simona
    # asked for by name, on ceart: what was asked for
    assert params(washout="default") == simona
    assert params(washout="gentle") == WashoutParams.preset("gentle").to_dict()


def test_the_mpcs_table_does_not_claim_a_sizing_check_it_did_not_make(ceart):
    """``tune --cueing mpc`` printed "saturated single-axis inputs (washout alone): largest
    use of the reach 0 % -> 0 %" for every set, although the check only runs for the
    classical washout (an MPC's usage is left at zero): a measurement that was never made,
    read as a set that uses none of the reach. The table now says it was not checked."""
    from motionbase.washout.mpc_params import MpcParams

    geometry, reach = ceart
    problem = tuning.TuningProblem(geometry, (load_script("rudder_kick@0:4"),), reach, cueing="mpc")
    score = problem.evaluate(MpcParams.load("tuned_ceart"))
    lines = tuning.format_table([("tuning set", score, score)]).splitlines()
    (sizing,) = [line for line in lines if line.startswith("saturated")]
    assert "not checked" in sizing and "%" not in sizing, sizing
    assert lines[-1].startswith("score tuned") and "use beyond the rule" not in lines[-1]
    assert score.cost == pytest.approx(score.manoeuvre_cost)
    # the classical washout's table still gives the check's figures
    classical = tuning.TuningProblem(geometry, (load_script("rudder_kick@0:4"),), reach)
    default = classical.evaluate(WashoutParams.preset("default"))
    text = tuning.format_table([("tuning set", default, default)])
    assert "largest use of the reach" in text and "not checked" not in text


def test_a_time_budget_counts_the_workers_start(monkeypatch, tmp_path):
    """``--time-budget`` bounds the time from the command's start: the worker processes'
    start (a minute or more on a loaded machine with an empty numba cache) is counted like
    the manoeuvres' loading. It used to be left out: the tuning was given the budget less
    the loading only, and a 6 s budget took 9 s with two workers."""
    import contextlib

    import motionbase.io.executors as executors

    @contextlib.contextmanager
    def slow_to_start(problem, **_):
        time.sleep(1.0)  # the workers import motionbase and set up
        yield lambda candidates: [problem.evaluate(p) for p in candidates]

    given: list[float] = []

    class Seen(Exception):
        pass

    def record(*_, time_budget_s=None, **__):
        given.append(time_budget_s)
        raise Seen

    monkeypatch.setattr(executors, "open_evaluator", slow_to_start)
    monkeypatch.setattr(tuning, "tune", record)
    with pytest.raises(Seen):
        app.tune(
            out=tmp_path / "t.toml", washout="default", scripts=["rudder_kick@0:6"],
            holdout=[], time_budget_s=60.0, progress=False,
        )  # fmt: skip
    assert given[0] <= 60.0 - 1.0  # the workers' second is gone from the budget
