"""Flight-phase profiles (ground/air, blended by the source's phase) and the translational
cue's own acceleration and velocity limits.

Real components: a JSBSim take-off (c1723 rolls on the runway and lifts off at about
24 s), a pymavlink vehicle sending EXTENDED_SYS_STATE over loopback UDP, MCAP logs read
back with the mcap reader.
"""

from __future__ import annotations

import dataclasses
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil

from motionbase import app
from motionbase.app import load_config
from motionbase.errors import ConfigError
from motionbase.io.jsbsim_source import JsbsimSource
from motionbase.io.mavlink_source import MavlinkSource
from motionbase.io.mcap_source import McapSource, read_messages
from motionbase.io.pipeline_log import PipelineLog
from motionbase.pipeline import Pipeline, run, with_overrides
from motionbase.state import AircraftState
from motionbase.washout.classical import ClassicalWashout
from motionbase.washout.params import MIN_PROFILE_BLEND_S, WashoutParams
from motionbase.washout.profiles import ProfiledCueing

G = 9.80665
RATE = 120.0
DT = 1.0 / RATE
PRESET = "profiles_example"
ML = mavutil.mavlink


def profiled_params(blend_s: float = 3.0) -> WashoutParams:
    """The default set in the air; on the ground a 3 deg tilt limit and a third of the pitch
    rate gain, so the two profiles' poses differ clearly at c1723's lift-off (surge, sway and
    pitch by 20 to 200 ticks' worth of their motion) without clamping on ceart."""
    base = WashoutParams.preset("default").to_dict()
    base["profile"] = {
        "blend_s": blend_s,
        "ground": {
            "scaling": {"angular_velocity_gain": [0.5, 0.15, 0.5]},
            "tilt": {"angle_limit_deg": 3.0},
        },
        "air": {},
    }
    return WashoutParams.from_dict(base, source="test profiles")


def states_of(messages: list[dict]) -> list[AircraftState]:
    return [
        AircraftState(
            m["source_t"],
            m["specific_force"],
            m["angular_velocity"],
            m["attitude"],
            on_ground=m.get("on_ground"),
        )
        for m in messages
    ]


@pytest.fixture(scope="module")
def take_off(tmp_path_factory):
    """c1723's first 30 s (ground roll, lift-off at ~24.3 s) flown with profiles, logged."""
    path = tmp_path_factory.mktemp("profiles") / "takeoff.mcap"
    params = profiled_params()
    toml = path.with_suffix(".toml")
    params.to_toml(toml)
    app.fly("c1723", washout=str(toml), duration_s=30.0, out=path, progress=False)
    return params, read_messages(path), path


# ------------------------------------------------------------------ the phase at the source


def test_jsbsim_weight_on_wheels_is_the_phase_and_matches_the_height():
    """On the runway until lift-off, then in the air: the phase follows the gear's contact,
    checked against JSBSim's height above ground (the c172's gear holds it ~1.3 m up)."""
    with JsbsimSource("c1723", rate_hz=RATE, duration_s=30.0) as src:
        fdm = src._fdm
        rows = []
        for state in src:
            rows.append((state.t, state.on_ground, fdm["position/h-agl-ft"] * 0.3048))
    t, ground, agl = (np.array(c) for c in zip(*rows, strict=True))
    assert ground.dtype == bool
    assert ground[0] and not ground[-1]
    lift = int(np.argmax(~ground))
    assert (ground[:lift]).all() and (~ground[lift:]).all()  # one change: the lift-off
    assert 20.0 < t[lift] < 28.0
    assert agl[:lift].max() < agl[lift:].max() - 3.0  # it climbs once airborne
    assert agl[-1] > agl[lift] + 3.0


def test_mavlink_extended_sys_state_sets_the_phase_over_udp():
    """A real pymavlink vehicle over loopback: ON_GROUND, TAKEOFF, IN_AIR, UNDEFINED (keeps
    the last phase), LANDING, ON_GROUND. Every tick carries the landed state of the sample
    whose IMU values it holds (or of the one before: it may have read the IMU message of a
    sample and not yet its EXTENDED_SYS_STATE)."""
    n = 150  # samples at 100 Hz: 1.5 s

    def landed(i: int) -> int:
        steps = [
            ML.MAV_LANDED_STATE_ON_GROUND,
            ML.MAV_LANDED_STATE_TAKEOFF,
            ML.MAV_LANDED_STATE_IN_AIR,
            ML.MAV_LANDED_STATE_UNDEFINED,
            ML.MAV_LANDED_STATE_LANDING,
            ML.MAV_LANDED_STATE_ON_GROUND,
        ]
        return steps[min(i * len(steps) // n, len(steps) - 1)]

    def expected(i: int) -> bool | None:  # UNDEFINED keeps the last known phase
        j = i
        while j >= 0 and landed(j) == ML.MAV_LANDED_STATE_UNDEFINED:
            j -= 1
        return None if j < 0 else landed(j) == ML.MAV_LANDED_STATE_ON_GROUND

    def send(mav, i: int) -> None:
        if i >= n:
            return
        f = (0.01 * i, 0.0, -G)  # sample i's own specific force identifies it
        mav.highres_imu_send(i * 10_000, *f, 0.0, 0.0, 0.0, 0, 0, 0, 1013.0, 0, 0, 20.0, 0x3F)
        mav.attitude_send(i * 10, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        mav.extended_sys_state_send(ML.MAV_VTOL_STATE_UNDEFINED, landed(i))

    from test_mavlink_source import sender  # the real pymavlink sender thread

    with MavlinkSource(
        "udpin:127.0.0.1:0", rate_hz=100.0, duration_s=2.2, request_streams=False
    ) as src:
        with sender(src.local_address[1], send) as sent:
            ticks = [(state, src.tick) for state in src]
    assert len(sent) >= n
    seen = []
    for state, tick in ticks:
        if not tick.fresh and state.specific_force[0] == 0.0 and state.on_ground is None:
            continue  # before the first message
        i = round(float(np.float32(state.specific_force[0])) / 0.01)
        assert abs(state.specific_force[0] - 0.01 * i) < 1e-6
        assert state.on_ground in {expected(i), expected(i - 1)}, (i, state.on_ground)
        seen.append(state.on_ground)
    # (the first sample's IMU may come before its first EXTENDED_SYS_STATE: no phase yet)
    while seen and seen[0] is None:
        seen.pop(0)
    changes = [g for k, g in enumerate(seen) if k == 0 or g != seen[k - 1]]
    assert changes == [True, False, True]  # UNDEFINED in the air changed nothing

    # the pipeline takes the phase from those states: the profiled cueing follows it
    config = load_config(washout=PRESET, rate_hz=100.0)
    pipe = Pipeline(config)
    assert isinstance(pipe.cueing, ProfiledCueing)
    profiles = []
    for state, _ in ticks:
        pipe.step(state)
        profiles.append(pipe.cueing.profile)
    runs = [p for k, p in enumerate(profiles) if k == 0 or p != profiles[k - 1]]
    # the file's own values run until the first phase (none when the first tick had one)
    first = ["base"] if ticks[0][0].on_ground is None else []
    assert runs == [*first, "ground", "air", "ground"]


def test_a_recordings_phase_is_read_back(take_off, tmp_path):
    """The log writes ``on_ground``; a replay of it feeds the same phases back and
    reproduces the profiled run exactly."""
    params, msgs, path = take_off
    phases = [m.get("on_ground") for m in msgs["/aircraft/state"]]
    assert set(phases) == {True, False}
    with McapSource(path) as src:
        assert [s.on_ground for s in src] == phases
    result = app.replay(path, check=True, progress=False)
    assert not result.failed, "\n".join(result.notes)


# ------------------------------------------------------------------ the blend


def test_take_off_switches_profile_with_a_continuous_pose(take_off):
    """Before lift-off the pose is the ground profile's alone, after the blend the air
    profile's alone (each run on its own from the same samples); in between, the smoothstep
    blend of the two. No step: the pose's rate and acceleration during the blend stay
    within what either profile gives plus the blend's own share, while a hard switch would
    have jumped by the profiles' difference."""
    params, msgs, _ = take_off
    states = states_of(msgs["/aircraft/state"])
    cue = np.array([m["pose"] for m in msgs["/washout/pose"][: len(states)]])
    assert not any(m["clamped"] for m in msgs["/platform/pose"])  # no anti-windup

    def alone(name: str) -> np.ndarray:
        washout = ClassicalWashout(params.for_profile(name), DT)
        return np.array([washout.step(s.specific_force, s.angular_velocity) for s in states])

    ground, air = alone("ground"), alone("air")
    on = np.array([s.on_ground for s in states])
    lift = int(np.argmax(~on))
    blend = int(round(params.profile_blend_s * RATE))
    assert np.array_equal(cue[:lift], ground[:lift])
    assert np.array_equal(cue[lift + blend :], air[lift + blend :])
    s = np.clip((np.arange(len(states)) - lift + 1) / blend, 0.0, 1.0)
    h = (s * s * (3 - 2 * s))[:, None]
    np.testing.assert_allclose(cue, (1 - h) * ground + h * air, rtol=0, atol=1e-12)
    # the profiles differ at lift-off: a hard switch would step by this
    jump = np.abs(air[lift] - ground[lift])
    rate = np.abs(np.diff(cue, axis=0))[lift - 1 : lift + blend + 1]
    alone_rate = np.maximum(np.abs(np.diff(ground, axis=0)), np.abs(np.diff(air, axis=0)))
    spread = np.abs(ground - air)[lift - 1 : lift + blend + 1].max(axis=0)
    dh = 1.5 / blend  # largest smoothstep change per tick
    assert (jump > 10 * rate.max(axis=0)).sum() >= 2
    assert (rate <= alone_rate[lift - 1 : lift + blend + 1] + dh * spread + 1e-12).all()
    acc = np.abs(np.diff(cue, 2, axis=0))[lift - 2 : lift + blend + 1]
    alone_acc = np.maximum(np.abs(np.diff(ground, 2, axis=0)), np.abs(np.diff(air, 2, axis=0)))
    vel_spread = np.abs(np.diff(ground - air, axis=0)).max(axis=0)
    d2h = 6.0 / blend**2  # largest smoothstep second difference per tick
    bound = alone_acc[lift - 2 : lift + blend + 1] + 2 * dh * vel_spread + d2h * spread + 1e-12
    assert (acc <= bound).all()


def test_the_log_records_the_phase_and_the_blend(take_off):
    params, msgs, _ = take_off
    on = [m["on_ground"] for m in msgs["/aircraft/state"]]
    cue = msgs["/washout/pose"][: len(on)]
    lift = on.index(False)
    assert all(m["profile"] == "ground" for m in cue[:lift])
    assert all(m["profile"] == "air" for m in cue[lift:])
    w_air = np.array([m["profile_weights"]["air"] for m in cue])
    w_ground = np.array([m["profile_weights"]["ground"] for m in cue])
    np.testing.assert_allclose(w_air + w_ground, 1.0, atol=1e-12)
    assert (w_air[:lift] == 0).all() and (w_air[lift + 360 :] == 1).all()
    assert (np.diff(w_air) >= 0).all()
    mid = lift + 180 - 1  # half-way through the 3 s blend
    assert abs(w_air[mid] - 0.5) < 0.01


def test_a_phase_reversal_mid_blend_is_continuous():
    """Lift-off, then touch-down half-way through the blend: the weights turn back from
    where they are (no jump), and settle on the ground profile."""
    params = profiled_params(blend_s=1.0)
    cueing = ProfiledCueing(ClassicalWashout, params, DT)
    u = np.array([1.0, 0.5, -G - 1.0, 0.1, -0.1, 0.05])
    out = np.empty(6)
    weights = []
    for k in range(600):
        cueing.set_flight_phase(not 100 <= k < 160)  # in the air for 0.5 s
        cueing.advance(u, out)
        weights.append(cueing.weights["ground"])
    w = np.array(weights)
    assert (w[:100] == 1).all() and 0.3 < w[159] < 0.7  # turned back half-way
    assert np.abs(np.diff(w)).max() <= 1.5 / RATE + 1e-12
    assert w[-1] == 1.0


def test_a_profiled_plugin_logs_the_diagnostics_of_the_profile_it_runs():
    """A cueing plug-in with diagnostics keeps its topic's schema under profiles, and the
    diagnostics are those of the profile the weights go to."""
    from motionbase.io.pipeline_log import cueing_schema

    class Counting(ClassicalWashout):
        name = "test_counting"
        diagnostics_schema = ("test.Counting", {"type": "object"})

        def diagnostics(self) -> dict[str, float]:
            return {"tilt_limit_deg": float(self.params.tilt_angle_limit_deg[1])}

    params = profiled_params(blend_s=1.0)
    cueing = ProfiledCueing(Counting, params, DT)
    cueing.set_flight_phase(True)
    cueing.advance(np.array([0.0, 0.0, -G, 0.0, 0.0, 0.0]), np.empty(6))
    assert cueing.name == "test_counting"  # its topic: /cueing/test_counting
    assert cueing_schema(cueing) == Counting.diagnostics_schema
    message = cueing.diagnostics()
    assert message == {"tilt_limit_deg": params.for_profile("ground").tilt_angle_limit_deg[1]}
    assert params.for_profile("ground").tilt_angle_limit_deg != params.tilt_angle_limit_deg


def test_the_phase_known_before_the_first_sample_starts_there():
    """A flight that starts on the ground runs the ground profile from its first sample,
    bit for bit (nothing was sent yet, so no blend); reset() forgets the phase."""
    params = profiled_params()
    cueing = ProfiledCueing(ClassicalWashout, params, DT)
    ground = ClassicalWashout(params.for_profile("ground"), DT)
    rng = np.random.default_rng(3)
    for _ in range(2):
        cueing.reset()
        ground.reset()
        out = np.empty(6)
        for k in range(300):
            u = np.concatenate([rng.normal(0, 1.0, 3) + (0, 0, -G), rng.normal(0, 0.1, 3)])
            cueing.set_flight_phase(True)
            assert cueing.advance(u, out)
            assert np.array_equal(out, ground.step(u[:3], u[3:])), k


def test_a_rejected_samples_phase_is_not_taken():
    """A sample the pipeline rejects (a NaN, a time that goes back: a late packet of the
    ground run) is replaced by the held one, its flight phase too: on the ground, one
    rejected sample that says "in the air" started a blend toward the air profile."""
    config = with_overrides(load_config(rate_hz=RATE), cueing_params=profiled_params())
    pipe = Pipeline(config)
    level = (0.0, 0.0, -G)
    for k in range(1, 240):
        pipe.step(AircraftState(k * DT, level, (0.0, 0.0, 0.0), on_ground=True))
    for bad in (
        AircraftState(240 * DT, (math.nan, 0.0, -G), (0.0, 0.0, 0.0), on_ground=False),
        AircraftState(100 * DT, level, (0.0, 0.0, 0.0), on_ground=False),  # time goes back
    ):
        pipe.step(bad)
        assert pipe.health.rejected_inputs and pipe.cueing.profile == "ground"
    pipe.step(AircraftState(241 * DT, level, (0.0, 0.0, 0.0), on_ground=False))
    assert pipe.cueing.profile == "air"  # an accepted one is taken


def test_without_a_phase_the_files_own_values_run():
    """A source that gives no phase (an old recording, X-Plane): the base values, exactly
    the classical washout of the file without its profiles."""
    params = profiled_params()
    cueing = ProfiledCueing(ClassicalWashout, params, DT)
    base = ClassicalWashout(params.for_profile(None), DT)
    assert base.params == dataclasses.replace(params, profiles=())
    out = np.empty(6)
    for k in range(200):
        u = np.array([math.sin(0.05 * k), 0.3, -G, 0.1, 0.0, -0.05 * math.cos(0.1 * k)])
        cueing.advance(u, out)
        assert np.array_equal(out, base.step(u[:3], u[3:]))
    assert cueing.profile == "base"


def test_run_batch_with_phases_equals_the_tick(take_off):
    params, msgs, _ = take_off
    states = states_of(msgs["/aircraft/state"])[2700:3300]  # across the lift-off
    config = with_overrides(load_config(rate_hz=RATE), cueing_params=params)
    ticked, batch = Pipeline(config), Pipeline(config)
    poses = np.array([ticked.step(s).platform_pose for s in states])
    on = np.array([float(s.on_ground) for s in states])
    result = batch.run_batch(
        np.array([s.t for s in states]),
        np.array([s.specific_force for s in states]),
        np.array([s.angular_velocity for s in states]),
        np.array([s.attitude for s in states]),
        on_ground=on,
    )
    assert np.array_equal(result.poses, poses)
    assert batch.cueing.weights == ticked.cueing.weights


# ------------------------------------------------------------------ the parameter file


def test_profile_tables_round_trip_and_override_only_what_they_name(tmp_path):
    params = WashoutParams.load(PRESET)
    assert params.profile_names == ("ground", "air")
    path = tmp_path / "p.toml"
    params.to_toml(path)
    assert WashoutParams.from_toml(path) == params
    ground = params.for_profile("ground")
    assert ground.specific_force_gain == (0.5, 0.5, 0.7)
    assert ground.translational_accel_limit == (1.5, 0.0, 0.0)
    assert ground.tilt_wn == params.tilt_wn  # not overridden: the file's own
    assert params.for_profile("air") == dataclasses.replace(params, profiles=())
    # a file without profiles or limits writes neither (logs and presets unchanged)
    plain = WashoutParams.preset("default").to_dict()
    assert "profile" not in plain and "accel_limit" not in plain["translational"]


@pytest.mark.parametrize(
    ("profile", "words"),
    [
        ({"cruise": {}}, ["unknown field 'cruise'", "[profile]"]),
        ({"ground": {"tilt": {"angle_limit_deg": 95}}}, ["[profile.ground]", "angle_limit_deg"]),
        ({"air": {"tilt": {"wm": 1.0}}}, ["[profile.air] [tilt]", "'wm'"]),
        ({"blend_s": -1.0}, ["profile.blend_s", ">= 0.5 s"]),
        ({"blend_s": 0}, ["profile.blend_s", ">= 0.5 s"]),  # a switch at once: a step
        ({"ground": {"translational": {"accel_limit": [1, -1, 0]}}}, ["accel_limit", ">= 0"]),
    ],
)
def test_bad_profile_tables_are_one_line_naming_the_file_and_field(tmp_path, profile, words):
    d = WashoutParams.preset("default").to_dict()
    d["profile"] = profile
    with pytest.raises(ConfigError) as err:
        WashoutParams.from_dict(d, source="my.toml")
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith("my.toml")
    for word in words:
        assert word in msg


def test_a_blend_too_short_to_be_smooth_is_refused():
    """A blend of 0 s (or of a tick) switched at once: on a bouncing landing, whose phase
    flips every tick, the cue jumped by the profiles' difference every tick (0.46 m a tick in
    surge here, against the ground profile's 0.1 m/s). The shortest blend allowed keeps the
    cue's speed within the faster profile's own plus the blend's share of their difference."""
    d = profiled_params().to_dict()
    limits = {"accel_limit": [1.0, 0, 0], "velocity_limit": [0.1, 0, 0]}
    d["profile"]["ground"]["translational"] = limits
    for short in (0.0, DT / 2):
        d["profile"]["blend_s"] = short
        with pytest.raises(ConfigError, match=r"profile\.blend_s.*>= 0\.5 s"):
            WashoutParams.from_dict(d, source="bounce.toml")
    d["profile"]["blend_s"] = MIN_PROFILE_BLEND_S
    params = WashoutParams.from_dict(d, source="bounce.toml")
    cueing = ProfiledCueing(ClassicalWashout, params, DT)
    alone = {n: ClassicalWashout(params.for_profile(n), DT) for n in ("ground", "air")}
    out, cue, poses = np.empty(6), [], {"ground": [], "air": []}
    for k in range(1200):  # on the ground 2 s, then a bounce: the phase flips every tick
        u = np.array([3.0 * math.sin(k / 100), 0.5, -G, 0.0, 0.05, 0.0])
        cueing.set_flight_phase(k < 240 or k % 2 == 0)
        cueing.advance(u, out)
        cue.append(out.copy())
        for name, washout in alone.items():
            poses[name].append(washout.step(u[:3], u[3:]))
    ground, air = np.array(poses["ground"]), np.array(poses["air"])
    rate = np.abs(np.diff(cue, axis=0))
    alone_rate = np.maximum(np.abs(np.diff(ground, axis=0)), np.abs(np.diff(air, axis=0)))
    dh = 1.5 * DT / MIN_PROFILE_BLEND_S  # largest smoothstep change per tick
    assert (rate <= alone_rate + dh * np.abs(ground - air)[1:] + 1e-12).all()


def test_a_bad_profile_on_the_command_line_exits_2_in_one_line(tmp_path):
    path = tmp_path / "bad.toml"
    WashoutParams.load(PRESET).to_toml(path)
    text = path.read_text()
    assert "[profile.air" in text
    path.write_text(text.replace("[profile.air", "[profile.cruise", 1))
    proc = subprocess.run(
        [sys.executable, "-m", "motionbase.cli", "fly", "--params", str(path), "--duration", "1"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "cruise" in lines[0] and "Traceback" not in proc.stderr


# ------------------------------------------------------------------ per-axis cue limits


def step_flight(seconds: float = 40.0) -> list[AircraftState]:
    """Level flight, then a 2 m/s^2 forward, -2 m/s^2 sideways and (for 2 s) 2 m/s^2
    downward specific-force step at 1 s, held: the washout must bring the cue back."""
    n = int(seconds * RATE)
    out = []
    for k in range(n):
        t = k * DT
        f = [0.0, 0.0, -G]
        if t >= 1.0:
            f[0] += 2.0
            f[1] -= 2.0
            if t < 3.0:
                f[2] += 2.0
        out.append(AircraftState(t, f, (0.0, 0.0, 0.0)))
    return out


def fly_logged(params: WashoutParams, states, path: Path) -> dict:
    config = with_overrides(load_config(rate_hz=RATE), cueing_params=params)
    pipe = Pipeline(config)
    with PipelineLog(path, config.to_dict()) as log:
        run(pipe, states, [log])
    return read_messages(path)


def test_cue_limits_bound_the_logged_cue_and_it_still_converges(tmp_path):
    """Per axis, the logged cue's velocity and acceleration (finite differences) stay within
    the limits set, where the unlimited washout exceeds them; the cue returns to neutral,
    with a velocity limit without overshooting the unlimited cue's excursion (an
    acceleration limit alone lets the lagging cue catch up past it: README), and the
    rotations are untouched."""
    amax, vmax = (0.4, 0.3, 0.0), (0.05, 0.0, 0.03)  # x both, y accel only, z velocity only
    base = WashoutParams.preset("default")
    limited = dataclasses.replace(
        base, translational_accel_limit=amax, translational_velocity_limit=vmax
    )
    states = step_flight()
    free = read_messages_pose(fly_logged(base, states, tmp_path / "free.mcap"))
    msgs = fly_logged(limited, states, tmp_path / "limited.mcap")
    assert not any(m["clamped"] for m in msgs["/platform/pose"])
    cue = read_messages_pose(msgs)
    n = len(states)
    vel = np.diff(cue[:n, :3], axis=0) / DT
    acc = np.diff(vel, axis=0) / DT
    vel_free = np.diff(free[:n, :3], axis=0) / DT
    acc_free = np.diff(vel_free, axis=0) / DT
    for i in range(3):
        if amax[i]:
            assert np.abs(acc[:, i]).max() <= amax[i] * (1 + 1e-6)
            assert np.abs(acc_free[:, i]).max() > 2 * amax[i]  # the limit acted
        if vmax[i]:
            assert np.abs(vel[:, i]).max() <= vmax[i] * (1 + 1e-9)
            assert np.abs(vel_free[:, i]).max() > 2 * vmax[i]
        peak = np.abs(free[:n, i]).max()
        if vmax[i]:
            assert np.abs(cue[:n, i]).max() <= peak  # no overshoot past it
        assert abs(cue[n - 1, i]) < 0.02 * peak  # back near neutral
    np.testing.assert_array_equal(cue[:n, 3:], free[:n, 3:])  # rotations untouched


def read_messages_pose(msgs: dict) -> np.ndarray:
    return np.array([m["pose"] for m in msgs["/washout/pose"]])


def test_cue_limits_off_by_default_change_no_number():
    """Limits of 0 (the default) leave the washout bit-identical."""
    base = WashoutParams.preset("default")
    same = dataclasses.replace(base, translational_accel_limit=(0.0, 0.0, 0.0))
    states = step_flight(10.0)
    f = np.array([s.specific_force for s in states])
    w = np.array([s.angular_velocity for s in states])
    ref = ClassicalWashout(base, DT).run(f, w)
    assert np.array_equal(ClassicalWashout(same, DT).run(f, w), ref)


def test_a_clamped_limited_cue_continues_from_the_achieved_pose():
    """Anti-windup with the limiter on: after ``track`` the cue starts from the achieved
    position at rest toward the cut, and still respects its limits on the way back."""
    params = dataclasses.replace(
        WashoutParams.preset("default"),
        translational_accel_limit=(0.5, 0.5, 0.5),
        translational_velocity_limit=(0.1, 0.1, 0.1),
    )
    washout = ClassicalWashout(params, DT)
    f, w = np.array([2.5, 0.0, -G]), np.zeros(3)
    xs = []
    for _ in range(int(20 * RATE)):
        pose = washout.step(f, w)
        if pose[0] > 0.05:  # a platform that reaches 5 cm forward
            pose[0] = 0.05
            washout.track(pose)
        xs.append(pose[0])
    x = np.array(xs)
    assert x.max() == 0.05
    back = int(np.flatnonzero(x == 0.05)[-1])  # the last clamped tick: the way back starts
    vel = np.diff(x[back:]) / DT
    assert vel[0] <= 0.0 and np.abs(vel).max() <= 0.1 * (1 + 1e-9)
    assert np.abs(np.diff(vel)).max() / DT <= 0.5 * (1 + 1e-6)
    assert abs(x[-1]) < 0.01
