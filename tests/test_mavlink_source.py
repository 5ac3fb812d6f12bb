"""MavlinkSource against real pymavlink senders on loopback UDP and real logs.

Every live test runs a real pymavlink connection in a thread (or, where its timing
matters, in another process: ``mavlink_sender.py``), sending to the source's ``udpin``
port (bound to port 0: a free port, no race). Each test is bounded by the source's
``duration_s``.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import socket
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mavlink_sender import att_values, imu_values, send_good, send_loop
from scipy.spatial.transform import Rotation

from motionbase.errors import ConfigError, SourceError
from motionbase.io.live_source import MIN_READS
from motionbase.io.mavlink_source import (
    MAX_LOG_GAP_S,
    REBOOT_S,
    MavlinkSource,
    MavlinkStats,
    load_signing_key,
    mavutil,
)
from motionbase.io.mcap_source import read_messages

G = 9.80665
# Real flight logs, not shipped with the repository: tests that read them take the
# ``flight_data`` fixture (tests/conftest.py: the folder $MOTIONBASE_TEST_DATA, or a skip).
TLOG = "vtol.tlog"
BIN = "erle_plane_329.BIN"
ML = mavutil.mavlink


# --------------------------------------------------------------------------- helpers


def f32(values: tuple[float, ...]) -> tuple[float, ...]:
    """What a MAVLink float field carries: the value rounded to float32."""
    return tuple(float(np.float32(v)) for v in values)


@contextmanager
def sender(
    port: int,
    make: Callable[[Any, int], None],
    *,
    sysid: int = 1,
    compid: int = 1,
    rate_hz: float = 100.0,
    key: bytes | None = None,
    link_id: int = 0,
    phases: tuple[tuple[float, float], ...] | None = None,
) -> Iterator[list[int]]:
    """Run a real pymavlink sender in a thread; yield the list of indices sent.

    ``phases`` is a tuple of (start_s, stop_s) windows, from the sender's start,
    during which it sends; None sends until the context exits.
    """
    stop = threading.Event()
    sent: list[int] = []
    conn = mavutil.mavlink_connection(
        f"udpout:127.0.0.1:{port}", source_system=sysid, source_component=compid
    )
    if key is not None:
        conn.setup_signing(key, sign_outgoing=True, link_id=link_id)

    errors: list[BaseException] = []

    def run() -> None:
        try:
            send_loop(conn.mav, make, sent, rate_hz, phases, stop)
        except BaseException as exc:  # surfaced in the test thread below
            errors.append(exc)

    th = threading.Thread(target=run, daemon=True)
    th.start()
    try:
        yield sent
    finally:
        stop.set()
        th.join(timeout=5)
        conn.close()
    if errors:
        raise errors[0]


@contextmanager
def sender_process(port: int, phases: tuple[tuple[float, float], ...]) -> Iterator[list[int]]:
    """Run ``send_good`` at 100 Hz during ``phases`` in another process (``mavlink_sender``);
    enter once it is connected; the list yielded holds the indices sent once the block ends
    (the block must outlast the last phase)."""
    script = Path(__file__).with_name("mavlink_sender.py")
    proc = subprocess.Popen(
        [sys.executable, str(script), str(port), "100", json.dumps(phases)],
        stdout=subprocess.PIPE,
        text=True,
    )
    sent: list[int] = []
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "ready"
        yield sent
        out, _ = proc.communicate(timeout=10)
        assert proc.returncode == 0
        sent.extend(json.loads(out))
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def run_live(src: MavlinkSource) -> list[tuple[Any, Any]]:
    """Iterate an open source to its duration; return (state, tick) pairs."""
    return [(state, src.tick) for state in src]


def index_of(table: dict[tuple[float, ...], int], values: np.ndarray) -> int:
    key = tuple(float(v) for v in values)
    assert key in table, f"state {key} was never sent by the accepted sender"
    return table[key]


def check_states_match_sent(ticks: list[tuple[Any, Any]], n: int, *, lossless: bool = True) -> int:
    """Every fresh state holds values of exactly one sent sample (never a blend or
    extrapolation) and the held sample never goes back in time; on a lossless link,
    IMU and attitude come from neighbouring samples. Returns the number of fresh
    ticks."""
    f_table = {f32(imu_values(i)[0]): i for i in range(n)}
    w_table = {f32(imu_values(i)[1]): i for i in range(n)}
    a_table = {f32(att_values(i)): i for i in range(n)}
    last_imu = last_att = -1
    fresh = 0
    for state, tick in ticks:
        if not tick.fresh:
            continue
        fresh += 1
        i_f = index_of(f_table, state.specific_force)
        assert index_of(w_table, state.angular_velocity) == i_f
        i_a = index_of(a_table, state.attitude)
        assert i_f >= last_imu and i_a >= last_att
        assert abs(i_f - i_a) <= 1 or not lossless
        last_imu, last_att = i_f, i_a
    return fresh


# --------------------------------------------------------------------------- live link


@pytest.mark.parametrize("busy_wait", [False, True], ids=["sleeping", "busy-waiting"])
def test_highres_imu_and_attitude_at_100hz_arrive_unchanged(busy_wait: bool) -> None:
    with MavlinkSource(
        "udpin:127.0.0.1:0",
        rate_hz=100.0,
        duration_s=2.0,
        request_streams=False,
        busy_wait=busy_wait,
    ) as src:
        host, port = src.local_address
        assert host == "127.0.0.1" and port > 0
        it = iter(src)
        first = (next(it), src.tick)  # before the sender starts
        with sender(port, send_good) as sent:
            ticks = [first] + [(state, src.tick) for state in it]
        stats = src.stats
    assert len(ticks) == 200
    # the fixed pipeline clock: t = k / rate, whatever the message timing
    assert [s.t for s, _ in ticks] == pytest.approx([k / 100.0 for k in range(200)])
    fresh = check_states_match_sent(ticks, len(sent) + 1)
    assert fresh > 100
    assert stats.used > 150 and stats.per_type["HIGHRES_IMU"] > 75
    assert stats.per_type["ATTITUDE"] > 75
    assert stats.imu_source == "HIGHRES_IMU"
    assert stats.rejected == 0 and stats.bad_data == 0
    assert 0 < stats.message_rate_hz < 1000
    for state, tick in ticks:
        assert state.is_finite()
        assert tick.fresh == (tick.sample_age_s <= src.stale_timeout_s)
    # before the first message: neutral state, marked stale, infinitely old
    state0, tick0 = ticks[0]
    assert not tick0.fresh and math.isinf(tick0.sample_age_s)
    np.testing.assert_array_equal(state0.specific_force, [0.0, 0.0, -G])
    np.testing.assert_array_equal(state0.attitude, [0.0, 0.0, 0.0])


def test_silent_sender_marks_ticks_stale_then_recovers() -> None:
    timeout = 0.2
    with MavlinkSource(
        "udpin:127.0.0.1:0",
        rate_hz=100.0,
        duration_s=2.2,
        stale_timeout_s=timeout,
        request_streams=False,
    ) as src:
        port = src.local_address[1]
        # the sender is another process: its timing holds when this one is busy
        with sender_process(port, phases=((0.0, 0.6), (1.3, 1.8))) as sent:
            ticks = run_live(src)
        stats = src.stats
    fresh = [t.fresh for _, t in ticks]
    # fresh, then a stale stretch (the gap), then fresh again; the gap is the longest stale
    # stretch (a busy machine that stalls the sender past the timeout makes short ones too)
    stretches, k = [], fresh.index(True)
    while False in fresh[k:]:
        start = fresh.index(False, k)
        k = fresh.index(True, start) if True in fresh[start:] else len(fresh)
        stretches.append((start, k))
    gap_start, resume = max(stretches, key=lambda s: s[1] - s[0])
    assert gap_start + 1 < resume < len(fresh)
    assert stats.gaps >= 1 and stats.stale_ticks >= resume - gap_start
    # staleness is declared exactly when the held sample exceeds the timeout
    for _, tick in ticks:
        assert tick.fresh == (tick.sample_age_s <= timeout)
    last_fresh_state, last_fresh_tick = ticks[gap_start - 1]
    first_stale_state, first_stale_tick = ticks[gap_start]
    assert last_fresh_tick.sample_age_s <= timeout < first_stale_tick.sample_age_s
    # during the gap the last state is held, not extrapolated, and time runs on; only the
    # gap's last tick may see a new message: the sender's first sample back can be half in
    # (its IMU read, its attitude not yet), which updates the IMU and leaves the tick stale
    held = [s for s, t in ticks[gap_start:resume] if t.arrival_s == last_fresh_tick.arrival_s]
    assert len(held) >= resume - gap_start - 1
    for state in held:
        np.testing.assert_array_equal(state.specific_force, last_fresh_state.specific_force)
        np.testing.assert_array_equal(state.attitude, last_fresh_state.attitude)
    ts = np.array([s.t for s, _ in ticks])
    np.testing.assert_allclose(np.diff(ts), 0.01)
    check_states_match_sent(ticks, max(sent) + 2)


def test_other_system_and_component_are_rejected_and_counted() -> None:
    def marker(mav: Any, i: int) -> None:
        mav.highres_imu_send(i, 7.0, 7.0, 7.0, 1.0, 1.0, 1.0, 0, 0, 0, 0, 0, 0, 0, 0x3F)
        mav.attitude_send(i, 1.0, 0.5, 1.0, 1.0, 1.0, 1.0)

    with MavlinkSource(
        "udpin:127.0.0.1:0", rate_hz=100.0, duration_s=1.5, compid=1, request_streams=False
    ) as src:
        port = src.local_address[1]
        with (
            sender(port, send_good) as sent,
            sender(port, marker, sysid=2) as other,
            sender(port, marker, sysid=1, compid=42) as other_comp,
        ):
            ticks = run_live(src)
        stats = src.stats
    assert check_states_match_sent(ticks, len(sent) + 1) > 50  # markers would fail lookup
    for state, _ in ticks:
        assert state.specific_force[0] != pytest.approx(7.0)
    assert stats.rejected_sysid >= len(other)  # two messages per sample
    assert stats.rejected_compid >= len(other_comp)
    assert stats.accepted < stats.received


def test_a_second_vehicle_with_the_same_ids_is_kept_out_while_the_first_sends(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A second vehicle (system 1, component 1 too, from another address) joins 0.3 s in:
    the states were the one or the other vehicle's, whichever message came last before a
    tick (two flights mixed on the platform, nothing said). Its messages are now counted
    and warned about once while the first vehicle sends; once the first falls silent (for
    longer than the stale timeout), the second one is used."""
    caplog.set_level(logging.WARNING, logger="motionbase")

    def marker(mav: Any, i: int) -> None:
        mav.highres_imu_send(i, 7.0, 7.0, -7.0, 1.0, 1.0, 1.0, 0, 0, 0, 0, 0, 0, 0, 0x3F)
        mav.attitude_send(i, 1.0, 0.5, 1.0, 1.0, 1.0, 1.0)

    with MavlinkSource("udpin:127.0.0.1:0", duration_s=2.5, request_streams=False) as src:
        port = src.local_address[1]
        with (
            sender(port, send_good, phases=((0.0, 1.2),)) as sent,
            sender(port, marker, rate_hz=37.0, phases=((0.3, 3.0),)),
        ):
            ticks = run_live(src)
        stats = src.stats
    second = [state.specific_force[0] == 7.0 for state, _ in ticks]
    took_over = second.index(True)
    assert all(second[took_over:])  # never the first vehicle again: it stopped at 1.2 s
    assert check_states_match_sent(ticks[:took_over], len(sent) + 1) > 50
    assert stats.rejected_sysid > 0
    warned = [r for r in caplog.records if "is heard from" in r.getMessage()]
    assert len(warned) == 1


def test_random_garbage_is_counted_and_never_reaches_the_state() -> None:
    rng = np.random.default_rng(6)
    with MavlinkSource(
        "udpin:127.0.0.1:0", rate_hz=100.0, duration_s=1.5, request_streams=False
    ) as src:
        port = src.local_address[1]
        stop = threading.Event()
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        n_junk = [0]

        def junk() -> None:
            while not stop.is_set():
                payload = rng.integers(0, 256, size=int(rng.integers(1, 200)), dtype=np.uint8)
                # garbage that starts with a MAVLink marker too, to reach the CRC check
                if n_junk[0] % 3 == 0:
                    payload[0] = 0xFD
                sock.sendto(payload.tobytes(), ("127.0.0.1", port))
                n_junk[0] += 1
                stop.wait(0.005)

        th = threading.Thread(target=junk, daemon=True)
        th.start()
        try:
            with sender(port, send_good) as sent:
                ticks = run_live(src)
        finally:
            stop.set()
            th.join(timeout=5)
            sock.close()
        stats = src.stats
    assert n_junk[0] > 50
    assert stats.bad_data > 0 and stats.bad_bytes > stats.bad_data
    # garbage never takes a real frame down with it (it took 6 of 150 IMU messages): only
    # the last sample may be in flight when the source stops
    assert stats.per_type["HIGHRES_IMU"] >= len(sent) - 1
    assert stats.per_type["ATTITUDE"] >= len(sent) - 1
    assert check_states_match_sent(ticks, len(sent) + 1) > 50
    assert all(s.is_finite() for s, _ in ticks)


def test_nan_inf_and_absurd_values_are_rejected() -> None:
    bad_imu = [
        (math.nan, 0.0, -G, 0.0, 0.0, 0.0),
        (0.0, math.inf, -G, 0.0, 0.0, 0.0),
        (1e6, 0.0, -G, 0.0, 0.0, 0.0),  # 100,000 g
        (0.0, 0.0, -G, 0.0, 500.0, 0.0),  # 500 rad/s
    ]
    bad_att = [(math.nan, 0.0, 0.0), (10.0, 0.0, 0.0), (0.0, 3.0, 0.0), (0.0, 0.0, -math.inf)]

    def mixed(mav: Any, i: int) -> None:
        send_good(mav, i)
        b = bad_imu[i % 4]
        mav.highres_imu_send(i, *b, 0, 0, 0, 0, 0, 0, 0, 0x3F)
        mav.attitude_send(i, *bad_att[i % 4], 0.0, 0.0, 0.0)

    with MavlinkSource(
        "udpin:127.0.0.1:0", rate_hz=100.0, duration_s=1.5, request_streams=False
    ) as src:
        with sender(src.local_address[1], mixed) as sent:
            ticks = run_live(src)
        stats = src.stats
    assert stats.rejected_invalid >= len(sent)  # two bad messages per sample
    assert check_states_match_sent(ticks, len(sent) + 1) > 50
    for state, _ in ticks:
        assert state.is_finite()
        assert np.all(np.abs(state.specific_force) < 20 * G)
        assert abs(state.attitude[0]) <= math.pi and abs(state.attitude[1]) <= math.pi / 2


def test_what_the_pipeline_would_reject_never_enters_the_held_state() -> None:
    """The source drops values beyond the pipeline's own plausibility bounds (one definition,
    :mod:`motionbase.physics`): a 16 g specific force or a 30 rad/s body rate (readable by a
    +-2000 deg/s gyro, absurd for an aircraft) is not held and handed on as the state."""
    from motionbase.safety import InputLimits, input_problem

    limits = InputLimits()
    beyond = [
        (1.07 * limits.max_specific_force, 0.0, -G, 0.0, 0.0, 0.0),
        (0.0, 0.0, -G, 0.0, 1.5 * limits.max_angular_velocity, 0.0),
    ]

    def mixed(mav: Any, i: int) -> None:
        send_good(mav, i)
        mav.highres_imu_send(i, *beyond[i % 2], 0, 0, 0, 0, 0, 0, 0, 0x3F)

    with MavlinkSource(
        "udpin:127.0.0.1:0", rate_hz=100.0, duration_s=1.0, request_streams=False
    ) as src:
        # (the sender stops 0.3 s before the source does, so that every message sent is read:
        # one bad message per sample; a message still in flight at the end made it flaky)
        with sender(src.local_address[1], mixed, phases=((0.0, 0.7),)) as sent:
            ticks = run_live(src)
        stats = src.stats
    assert stats.rejected_invalid >= len(sent)
    assert check_states_match_sent(ticks, len(sent) + 1) > 30
    for state, _ in ticks:
        f, w, att = state.specific_force, state.angular_velocity, state.attitude
        assert input_problem(0.0, f, w, att, None, limits) is None


def test_scaled_imu_and_attitude_quaternion_units_and_frames() -> None:
    """SCALED_IMU carries mG and mrad/s; ATTITUDE_QUATERNION is converted to
    Z-Y-X Euler angles (checked against scipy's Rotation)."""
    rng = np.random.default_rng(7)
    acc_mg = rng.integers(-2000, 2000, size=(4000, 3))
    acc_mg[:, 2] = rng.integers(-1200, -800, size=4000)  # roughly level: z reads ~ -1000 mG
    gyr_mrad = rng.integers(-500, 500, size=(4000, 3))
    quats = Rotation.random(4000, random_state=8).as_quat()  # (x, y, z, w)

    def send(mav: Any, i: int) -> None:
        mav.scaled_imu_send(i, *map(int, acc_mg[i]), *map(int, gyr_mrad[i]), 0, 0, 0)
        x, y, z, w = quats[i]
        mav.attitude_quaternion_send(i, w, x, y, z, 0.0, 0.0, 0.0)

    with MavlinkSource(
        "udpin:127.0.0.1:0", rate_hz=100.0, duration_s=1.5, request_streams=False
    ) as src:
        with sender(src.local_address[1], send) as sent:
            ticks = run_live(src)
        stats = src.stats
    assert stats.imu_source == "SCALED_IMU"
    f_table = {tuple(acc_mg[i] * 9.80665e-3): i for i in range(len(sent) + 1)}
    n_fresh = 0
    for state, tick in ticks:
        if not tick.fresh:
            continue
        n_fresh += 1
        i = None
        for key, j in f_table.items():
            if np.allclose(state.specific_force, key, rtol=0, atol=1e-9):
                i = j
                break
        assert i is not None, "specific force is not a sent SCALED_IMU sample in m/s^2"
        np.testing.assert_allclose(state.angular_velocity, gyr_mrad[i] * 1e-3, atol=1e-12)
        # the attitude belongs to sample i or i-1 (sent just before/after the IMU)
        r = Rotation.from_euler("ZYX", state.attitude[::-1])
        dists = [(r.inv() * Rotation.from_quat(quats[j])).magnitude() for j in (i, i - 1) if j >= 0]
        assert min(dists) < 1e-5  # float32 quaternion
    assert n_fresh > 50
    # level-ish samples read about -1 g on z, i.e. specific force, FRD
    zs = [s.specific_force[2] for s, t in ticks if t.fresh]
    assert -1.25 * G < np.mean(zs) < -0.75 * G


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_raw_imu_used_only_from_ardupilot(autopilot: str) -> None:
    ap = ML.MAV_AUTOPILOT_ARDUPILOTMEGA if autopilot == "ardupilot" else ML.MAV_AUTOPILOT_PX4

    def send(mav: Any, i: int) -> None:
        if i % 10 == 0:
            mav.heartbeat_send(ML.MAV_TYPE_FIXED_WING, ap, 0, 0, 0)
        mav.raw_imu_send(i, 10, -20, -1000, 5, -5, 50, 0, 0, 0)
        mav.attitude_send(i, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)

    with MavlinkSource(
        "udpin:127.0.0.1:0", rate_hz=100.0, duration_s=1.0, request_streams=False
    ) as src:
        with sender(src.local_address[1], send):
            ticks = run_live(src)
        stats = src.stats
    fresh = [s for s, t in ticks if t.fresh]
    if autopilot == "ardupilot":
        assert len(fresh) > 30 and stats.imu_source == "RAW_IMU"
        np.testing.assert_allclose(
            fresh[-1].specific_force, np.array([10, -20, -1000]) * 9.80665e-3
        )
        np.testing.assert_allclose(fresh[-1].angular_velocity, [0.005, -0.005, 0.05])
    else:  # raw sensor units per the MAVLink spec: not usable
        assert fresh == [] and stats.ignored_raw_imu > 30 and stats.used > 0


# --------------------------------------------------------------------------- signing


def signed_source(tmp_path: Path) -> tuple[bytes, MavlinkSource]:
    """A signing key (its file in ``tmp_path``) and a 1.5 s source that needs it."""
    key = bytes(range(32))
    key_file = tmp_path / "key.bin"
    key_file.write_bytes(key)
    source = MavlinkSource(
        "udpin:127.0.0.1:0",
        rate_hz=100.0,
        duration_s=1.5,
        signing_key=key_file,
        request_streams=False,
    )
    return key, source


def test_signing_rejects_unsigned_and_badly_signed(tmp_path: Path) -> None:
    key, source = signed_source(tmp_path)

    def marker(mav: Any, i: int) -> None:
        mav.highres_imu_send(i, 7.0, 7.0, -7.0, 1.0, 1.0, 1.0, 0, 0, 0, 0, 0, 0, 0, 0x3F)
        mav.attitude_send(i, 1.0, 0.5, 1.0, 1.0, 1.0, 1.0)

    with source as src:
        port = src.local_address[1]
        with (
            sender(port, send_good, key=key, link_id=1) as sent,
            sender(port, marker) as unsigned,
            sender(port, marker, key=bytes(32 * [0xAA]), link_id=2) as forged,
        ):
            ticks = run_live(src)
        stats = src.stats
        description = src.describe()
    assert check_states_match_sent(ticks, len(sent) + 1) > 50
    assert stats.rejected_unsigned >= len(unsigned)
    assert stats.rejected_bad_signature >= len(forged)
    assert stats.rejected_signature == stats.rejected_unsigned + stats.rejected_bad_signature
    assert description["signing"] is True
    assert key.hex() not in repr(description) and "key.bin" in repr(description)


def test_a_forged_frame_stamped_far_ahead_does_not_stop_a_signed_stream(tmp_path: Path) -> None:
    """One frame signed with another key, on the vehicle's link id, system and component,
    its signing timestamp near the largest there is: pymavlink kept that timestamp although
    the signature failed, and rejected every genuine frame after it as older (no state
    reached the pipeline; a keyless sender could stop a signed stream for good)."""
    key, source = signed_source(tmp_path)
    with source as src:
        port = src.local_address[1]
        forger = mavutil.mavlink_connection(
            f"udpout:127.0.0.1:{port}", source_system=1, source_component=1
        )
        forger.setup_signing(bytes(32 * [0xAA]), sign_outgoing=True, link_id=1)
        forger.mav.signing.timestamp = 2**48 - 100  # (10 us units: the 48-bit field's end)
        forger.mav.heartbeat_send(ML.MAV_TYPE_FIXED_WING, ML.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 0)
        forger.close()
        with sender(port, send_good, key=key, link_id=1) as sent:
            ticks = run_live(src)
        stats = src.stats
    assert stats.rejected_bad_signature == 1
    assert check_states_match_sent(ticks, len(sent) + 1) > 50


def test_a_pymavlink_without_the_signing_names_is_left_as_it_is() -> None:
    """The forged-timestamp workaround wraps pymavlink internals (``check_signature``,
    ``signing.stream_timestamps``). A parser without them (another pymavlink version) is
    left alone: the wrapping raised AttributeError when the link opened (a traceback), or
    on each signed frame."""
    from motionbase.io.mavlink_source import _forgeries_leave_stream_times

    mav = ML.MAVLink(None, srcSystem=1, srcComponent=1)  # (this pymavlink has both: wrapped)
    _forgeries_leave_stream_times(mav)
    assert "check_signature" in vars(mav)
    del mav.signing.stream_timestamps  # (a version that keeps them elsewhere)
    other = ML.MAVLink(None, srcSystem=1, srcComponent=1)
    other.signing = mav.signing
    _forgeries_leave_stream_times(other)
    assert "check_signature" not in vars(other)
    bare = type("Parser", (), {"signing": mav.signing})()  # no check_signature at all
    _forgeries_leave_stream_times(bare)
    assert not hasattr(bare, "check_signature")


def test_signing_key_file_errors(tmp_path: Path) -> None:
    short = tmp_path / "short.key"
    short.write_bytes(b"secret")
    with pytest.raises(ConfigError, match="32 raw bytes or 64 hex digits, got 6 bytes"):
        load_signing_key(short)
    with pytest.raises(ConfigError, match="cannot read"):
        MavlinkSource(signing_key=tmp_path / "missing.key")
    hex_file = tmp_path / "hex.key"
    hex_file.write_text(bytes(range(32)).hex().upper() + "\n")
    assert load_signing_key(hex_file) == bytes(range(32))
    with pytest.raises(ConfigError, match="live links only"):
        MavlinkSource(str(TLOG), signing_key=hex_file)
    # 64 characters, a newline: once "got 65 bytes", as if the length were wrong
    not_hex = tmp_path / "not_hex.key"
    not_hex.write_text("0123456789abcdef" * 2 + "zz" + "0" * 30 + "\n")
    with pytest.raises(ConfigError, match=r"'z' \(character 33\) is not a hexadecimal digit"):
        load_signing_key(not_hex)


# --------------------------------------------------------------------------- stream requests


def _vehicle(
    port: int, *, ack: bool, stop: threading.Event, got: list[Any], attitude: bool = False
) -> None:
    """A silent ArduPilot-like vehicle: heartbeats; answers SET_MESSAGE_INTERVAL only
    when ``ack``, then streams HIGHRES_IMU and ATTITUDE at the interval asked. With
    ``attitude`` it sends ATTITUDE at 50 Hz unasked until then (silent on the IMU only)."""
    conn = mavutil.mavlink_connection(
        f"udpout:127.0.0.1:{port}", source_system=1, source_component=1
    )
    mav = conn.mav
    interval = None
    next_hb = next_data = time.monotonic()
    i = 0
    try:
        while not stop.is_set():
            now = time.monotonic()
            if now >= next_hb:
                mav.heartbeat_send(ML.MAV_TYPE_FIXED_WING, ML.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 0)
                next_hb = now + 0.2
            msg = conn.recv_msg()
            while msg is not None:
                got.append(msg)
                if (
                    msg.get_type() == "COMMAND_LONG"
                    and msg.command == ML.MAV_CMD_SET_MESSAGE_INTERVAL
                    and ack
                ):
                    mav.command_ack_send(msg.command, ML.MAV_RESULT_ACCEPTED)
                    interval = msg.param2 * 1e-6
                msg = conn.recv_msg()
            if interval is not None and now >= next_data:
                send_good(mav, i)
                i += 1
                next_data = now + interval
            elif attitude and interval is None and now >= next_data:
                mav.attitude_send(i * 10, *att_values(i), 0.0, 0.0, 0.0)
                i += 1
                next_data = now + 0.02
            stop.wait(0.002)
    finally:
        conn.close()


def run_beside_vehicle(
    src: MavlinkSource, got: list[Any], delay_s: float = 0.0, **kw: Any
) -> list[tuple[Any, Any]]:
    """The live source's ticks (:func:`run_live`) while a :func:`_vehicle` (its keywords
    ``kw``, what it receives into ``got``) runs beside it, from ``delay_s`` on."""
    stop = threading.Event()
    th = threading.Timer(delay_s, _vehicle, args=(src.local_address[1],), kwargs=kw)
    th.kwargs.update(stop=stop, got=got)
    th.start()
    try:
        return run_live(src)
    finally:
        stop.set()
        th.cancel()
        th.join(timeout=5)


@pytest.mark.parametrize("ack", [False, True])
def test_stream_request_to_a_silent_vehicle(ack: bool, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, logger="motionbase")
    got: list[Any] = []
    with MavlinkSource(
        "udpin:127.0.0.1:0", rate_hz=50.0, duration_s=2.4, request_timeout_s=0.8
    ) as src:
        ticks = run_beside_vehicle(src, got, ack=ack)
        stats = src.stats
    requests = [
        m
        for m in got
        if m.get_type() == "COMMAND_LONG" and m.command == ML.MAV_CMD_SET_MESSAGE_INTERVAL
    ]
    asked = {int(m.param1) for m in requests}
    assert {ML.MAVLINK_MSG_ID_HIGHRES_IMU, ML.MAVLINK_MSG_ID_ATTITUDE} <= asked
    assert all(m.param2 == pytest.approx(1e6 / 50.0) for m in requests)
    assert all(m.target_system == 1 and m.get_srcSystem() == 255 for m in requests)
    assert any(m.get_type() == "HEARTBEAT" and m.type == ML.MAV_TYPE_GCS for m in got)
    warned = [r for r in caplog.records if "ignored MAV_CMD_SET_MESSAGE_INTERVAL" in r.message]
    if ack:
        assert not warned
        assert stats.stream_request == "streaming"
        assert any(t.fresh for _, t in ticks) and ticks[-1][1].fresh
    else:
        assert len(warned) == 1 and warned[0].levelno == logging.WARNING
        assert len(requests) >= 4  # asked again after the timeout
        assert not any(t.fresh for _, t in ticks)


def test_a_vehicle_that_sends_attitude_alone_is_asked_for_the_imu() -> None:
    """ATTITUDE arriving unasked, no IMU message (the platform moves on neither alone): the
    vehicle was never asked for HIGHRES_IMU, nothing warned, and every tick was stale, since
    the attitude kept the link from counting as silent. It is asked, and the ticks turn
    fresh once the IMU arrives."""
    got: list[Any] = []
    with MavlinkSource(
        "udpin:127.0.0.1:0", rate_hz=50.0, duration_s=2.4, request_timeout_s=0.8
    ) as src:
        ticks = run_beside_vehicle(src, got, ack=True, attitude=True)
    asked = {
        int(m.param1)
        for m in got
        if m.get_type() == "COMMAND_LONG" and m.command == ML.MAV_CMD_SET_MESSAGE_INTERVAL
    }
    assert ML.MAVLINK_MSG_ID_HIGHRES_IMU in asked
    assert ticks[-1][1].fresh


def test_a_vehicle_that_comes_after_the_requests_ran_out_is_asked(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """The vehicle starts after the stream (SITL started second): the stream requests all
    went out before it was there, and it was never asked again, so a vehicle that streams
    only when asked gave nothing for ever. Its first heartbeat opens a new round, without a
    warning that it ignored requests sent before it was there (one was given at its first
    heartbeat, before it was asked)."""
    caplog.set_level(logging.WARNING, logger="motionbase")
    got: list[Any] = []
    with MavlinkSource(
        "udpin:127.0.0.1:0", rate_hz=50.0, duration_s=4.5, request_timeout_s=0.3
    ) as src:
        ticks = run_beside_vehicle(src, got, 2.5, ack=True)  # (all 3 asked by 1.9 s)
    assert any(m.get_type() == "COMMAND_LONG" for m in got)
    assert ticks[-1][1].fresh
    assert not [r for r in caplog.records if "ignored" in r.getMessage()]


def test_a_vehicle_that_refuses_again_and_again_is_reported_once(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A vehicle that answers the stream request with a refusal, and keeps sending
    refusals (hundreds a second): one warning, not one per acknowledgement."""
    caplog.set_level(logging.WARNING, logger="motionbase")
    stop = threading.Event()
    with MavlinkSource(
        "udpin:127.0.0.1:0", rate_hz=50.0, duration_s=1.5, request_timeout_s=0.3
    ) as src:
        conn = mavutil.mavlink_connection(
            f"udpout:127.0.0.1:{src.local_address[1]}", source_system=1, source_component=1
        )

        def vehicle() -> None:
            while not stop.is_set():
                conn.mav.heartbeat_send(
                    ML.MAV_TYPE_FIXED_WING, ML.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 0
                )
                for _ in range(5):
                    conn.mav.command_ack_send(ML.MAV_CMD_SET_MESSAGE_INTERVAL, ML.MAV_RESULT_DENIED)
                stop.wait(0.01)

        th = threading.Thread(target=vehicle, daemon=True)
        th.start()
        try:
            run_live(src)
        finally:
            stop.set()
            th.join(timeout=5)
            conn.close()
    refused = [r for r in caplog.records if "refused MAV_CMD_SET_MESSAGE_INTERVAL" in r.message]
    assert len(refused) == 1, len(refused)


def test_a_datagram_cut_short_does_not_swallow_the_next_ones() -> None:
    """A 12-byte datagram (a MAVLink 2 header announcing 63 bytes of payload) after every
    good pair: pymavlink parses UDP as one byte stream, so each cut frame swallowed the
    next datagram's messages (8 of 600 IMU samples decoded, the link stale on 549 of 600
    ticks). The cut frame fails its checksum once the next datagram completes it, and
    parsing resumes at the next frame start after its own: the good ones are kept."""
    stop = threading.Event()
    sent: list[int] = []
    with MavlinkSource("udpin:127.0.0.1:0", rate_hz=50.0, duration_s=2.0) as src:
        port = src.local_address[1]
        conn = mavutil.mavlink_connection(
            f"udpout:127.0.0.1:{port}", source_system=1, source_component=1
        )
        raw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)

        def vehicle() -> None:
            i = 0
            while not stop.is_set():
                send_good(conn.mav, i)
                sent.append(i)
                raw.sendto(bytes([0xFD, 63, 0, 0, i & 255, 1, 1, 105, 0, 0, 0, 0]),
                           ("127.0.0.1", port))  # fmt: skip
                i += 1
                stop.wait(0.01)

        th = threading.Thread(target=vehicle, daemon=True)
        th.start()
        try:
            ticks = run_live(src)
        finally:
            stop.set()
            th.join(timeout=5)
            conn.close()
            raw.close()
        stats = src.stats
    fresh = sum(tick.fresh for _, tick in ticks)
    assert fresh >= 0.9 * len(ticks), (fresh, len(ticks))
    assert stats.accepted >= 1.5 * len(sent), (stats.accepted, len(sent))  # both of each pair


class _Frames:
    """A pymavlink vehicle's output captured frame by frame (``write`` gets one frame)."""

    def __init__(self, protocol: Any = ML) -> None:
        self.mav = protocol.MAVLink(self, srcSystem=1, srcComponent=1)
        self.frames: list[bytes] = []

    def write(self, data: bytes) -> None:
        self.frames.append(bytes(data))

    def good(self, i: int) -> tuple[bytes, bytes]:
        """The HIGHRES_IMU and ATTITUDE frames of sample i (``send_good``)."""
        self.frames.clear()
        send_good(self.mav, i)
        imu, att = self.frames
        return imu, att


def _run_raw(
    datagrams_of: Callable[[int], list[bytes]], n: int, **options: Any
) -> tuple[list[tuple[Any, Any]], MavlinkStats]:
    """Send ``datagrams_of(i)`` back to back for samples 0..n-1 at 100 per second from a
    raw socket (a bridge, or a broken sender) to a source at 100 Hz running 0.6 s longer;
    return its (state, tick) pairs and stats."""
    with MavlinkSource(
        "udpin:127.0.0.1:0",
        rate_hz=100.0,
        duration_s=n / 100.0 + 0.6,
        request_streams=False,
        **options,
    ) as src:
        port = src.local_address[1]
        raw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)

        def vehicle() -> None:
            t0 = time.monotonic()
            for i in range(n):
                for d in datagrams_of(i):
                    raw.sendto(d, ("127.0.0.1", port))
                time.sleep(max(0.0, t0 + (i + 1) / 100.0 - time.monotonic()))

        th = threading.Thread(target=vehicle, daemon=True)
        th.start()
        try:
            ticks = run_live(src)
        finally:
            th.join(timeout=5)
            raw.close()
        return ticks, src.stats


@pytest.mark.parametrize("protocol", ["v2", "v1"])
def test_frames_split_across_two_datagrams_are_reassembled(protocol: str) -> None:
    """A serial-to-UDP bridge (socat, ser2net) cuts the byte stream into datagrams anywhere:
    each frame here comes in two datagrams, back to back, cut at a different place each
    time. The start of a frame is kept until the rest arrives; it was thrown away, and 499
    of 500 frames were counted as garbled, every tick stale."""
    from pymavlink.dialects.v10 import ardupilotmega as ml1

    vehicle = _Frames(ML if protocol == "v2" else ml1)
    n = 80

    def split(i: int) -> list[bytes]:
        out = []
        for k, frame in enumerate(vehicle.good(i)):
            cut = 1 + (7 * i + 3 * k) % (len(frame) - 1)  # 1 .. len - 1: every place
            out += [frame[:cut], frame[cut:]]
        return out

    ticks, stats = _run_raw(split, n)
    assert stats.bad_data == 0 and stats.bad_bytes == 0
    assert stats.per_type["HIGHRES_IMU"] == n and stats.per_type["ATTITUDE"] == n
    assert check_states_match_sent(ticks, n) > n / 2


@pytest.mark.parametrize("where", ["tail", "head"])
def test_a_frame_cut_short_does_not_swallow_the_good_frames_after_it(where: str) -> None:
    """The first 12 bytes of an ATTITUDE frame, the rest lost: at the end of a datagram
    holding a whole HIGHRES_IMU ("tail"; the next datagram, the whole ATTITUDE, was lost with
    it), or at its start ("head"; the HIGHRES_IMU behind it, and the ATTITUDE after, were
    lost). The cut frame fails its checksum; parsing resumes at the next frame start after
    its first byte, so every whole frame decodes and the 12 bytes are one run of garbage."""
    vehicle = _Frames()
    n = 80

    def cut(i: int) -> list[bytes]:
        imu, att = vehicle.good(i)
        return [imu + att[:12], att] if where == "tail" else [att[:12] + imu, att]

    ticks, stats = _run_raw(cut, n)
    assert stats.per_type["HIGHRES_IMU"] == n and stats.per_type["ATTITUDE"] == n
    # "tail": the last cut frame may still wait for bytes that never come
    assert n - (where == "tail") <= stats.bad_data <= n
    assert stats.bad_bytes == 12 * stats.bad_data
    assert check_states_match_sent(ticks, n) > n / 2


@pytest.mark.parametrize(
    "prefix",
    [
        "a cut frame",  # 12 bytes of a FILE_TRANSFER_PROTOCOL frame: it waits for 266 bytes
        "a start byte",  # 0xFD with a length of 255: it waits for 267 bytes
        "an unknown message",  # a header of message id 0xEEEEEE: no checksum to check
    ],
)
def test_a_false_frame_start_yields_to_the_whole_frames_behind_it(prefix: str) -> None:
    """One datagram: a false frame start, then whole frames, then silence. A candidate frame
    still waiting for bytes is overtaken by a whole frame behind it that passes its checksum,
    and one whose checksum cannot be checked (a message the dialect does not know) yields to
    such a frame inside it; they kept the good frames (for ever, with nothing more to come)."""
    vehicle = _Frames()
    vehicle.mav.file_transfer_protocol_send(0, 1, 1, [0x55] * 251)
    long_frame = vehicle.frames[0]
    assert len(long_frame) == 266
    imu, att = vehicle.good(3)
    head = {
        "a cut frame": long_frame[:12],
        "a start byte": bytes([0xFD, 255]),
        "an unknown message": bytes([0xFD, 48, 0, 0, 9, 1, 1, 0xEE, 0xEE, 0xEE]),
    }[prefix]
    with MavlinkSource(
        "udpin:127.0.0.1:0", rate_hz=100.0, duration_s=0.1, request_streams=False
    ) as src:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as raw:
            raw.sendto(head + imu + att, src.local_address)
        ticks = run_live(src)
        stats = src.stats
    assert stats.per_type == {"HIGHRES_IMU": 1, "ATTITUDE": 1}
    assert stats.bad_data == 1 and stats.bad_bytes == len(head)
    state, tick = ticks[-1]
    assert tick.fresh
    np.testing.assert_array_equal(state.specific_force, f32(imu_values(3)[0]))
    np.testing.assert_array_equal(state.attitude, f32(att_values(3)))


def test_the_start_of_a_frame_is_kept_no_longer_than_partial_timeout_s() -> None:
    """The start of a frame waits at most ``partial_timeout_s`` for the rest; then it is
    garbage, so it can never join bytes that come later. With 0 s nothing waits: every frame
    split as a bridge splits it is lost, each byte counted once as garbage."""
    vehicle = _Frames()
    n = 30
    sent = 0

    def split(i: int) -> list[bytes]:
        nonlocal sent
        out = []
        for frame in vehicle.good(i):
            out += [frame[:20], frame[20:]]
            sent += len(frame)
        return out

    ticks, stats = _run_raw(split, n, partial_timeout_s=0.0)
    assert stats.per_type.get("HIGHRES_IMU", 0) == 0 and stats.per_type.get("ATTITUDE", 0) == 0
    assert sent - 280 < stats.bad_bytes <= sent  # the last bytes may still wait
    assert not any(tick.fresh for _, tick in ticks)
    with pytest.raises(ConfigError, match="partial_timeout_s"):
        MavlinkSource("udpin:127.0.0.1:0", partial_timeout_s=-1.0)


def test_a_tick_stops_reading_when_its_drain_budget_is_spent() -> None:
    """The same drain as the simulators' (a flood of messages held a tick back for up to
    10,000 of them, about 0.85 s): with a budget of 0 the first tick, due at once, decodes
    MIN_READS messages and holds the last; the rest wait in the socket, none lost."""
    n = 2 * MIN_READS + 5
    with MavlinkSource(
        "udpin:127.0.0.1:0", rate_hz=100.0, request_streams=False, drain_budget_s=0.0
    ) as src:
        port = src.local_address[1]
        conn = mavutil.mavlink_connection(
            f"udpout:127.0.0.1:{port}", source_system=1, source_component=1
        )
        try:
            for i in range(n):
                f, w = imu_values(i)
                conn.mav.highres_imu_send(i, *f, *w, 0, 0, 0, 1013.0, 0, 0, 20.0, 0x3F)
        finally:
            conn.close()
        it = iter(src)
        first = next(it)
        read_by_first_tick = src.stats.received
        while src.stats.received < n and src.stats.ticks < 100:
            next(it)
        stats = src.stats
    assert read_by_first_tick == MIN_READS
    np.testing.assert_array_equal(first.specific_force, f32(imu_values(MIN_READS - 1)[0]))
    assert stats.received == n and stats.per_type["HIGHRES_IMU"] == n


def _crafted_tlog(
    path: Path,
    boot_ms_of: Callable[[int], int],
    n: int = 600,
    values: Callable[[int], tuple[tuple[float, ...], tuple[float, ...]]] = imu_values,
    gimbal_ms_of: Callable[[int], int | None] | None = None,
) -> Path:
    """A .tlog of ``n`` HIGHRES_IMU + ATTITUDE pairs 10 ms apart (receive times too), the
    vehicle's boot time of pair ``i`` given by ``boot_ms_of(i)``, its specific force and
    body rates by ``values(i)`` (level attitude). With ``gimbal_ms_of``, another component
    of the system (154, a gimbal) sends an ATTITUDE before pair ``i``, stamped with its own
    boot time ``gimbal_ms_of(i)`` (None: none before that pair)."""

    class Capture:
        def __init__(self) -> None:
            self.frames: list[bytes] = []

        def write(self, data: bytes) -> None:
            self.frames.append(bytes(data))

    cap = Capture()
    mav = ML.MAVLink(cap, srcSystem=1, srcComponent=1)
    gimbal = ML.MAVLink(cap, srcSystem=1, srcComponent=154)
    rx0_us = 1_700_000_000 * 10**6
    with open(path, "wb") as fh:
        for i in range(n):
            boot_ms = boot_ms_of(i)
            f, w = values(i)
            cap.frames.clear()
            if gimbal_ms_of is not None and (gimbal_ms := gimbal_ms_of(i)) is not None:
                gimbal.attitude_send(gimbal_ms, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
            mav.highres_imu_send(boot_ms * 1000, *f, *w, 0, 0, 0, 1013, 0, 0, 20, 0x3F)
            mav.attitude_send(boot_ms & 0xFFFFFFFF, 0.1, 0.05, 0.0, *w)
            for frame in cap.frames:
                fh.write(struct.pack(">Q", rx0_us + i * 10_000) + frame)
    return path


def _replay_times(path: Path, compid: int | None = None) -> tuple[list[float], int]:
    with MavlinkSource(str(path), rate_hz=100.0, realtime=False, compid=compid) as src:
        times, fresh = [], 0
        for state in src:
            times.append(state.t)
            fresh += src.fresh
    return times, fresh


def test_a_log_whose_vehicle_clock_jumps_hours_ahead_holds_the_gap_briefly(tmp_path, caplog):
    """A 6 s log whose boot time jumps 5 hours ahead halfway: the replay held the gap for
    5 hours in real time (with --fast it computed every stale tick of it: 146 MB of log in
    25 s). The gap is held for MAX_LOG_GAP_S, the platform fading to neutral, and a warning
    says so."""
    log = _crafted_tlog(
        tmp_path / "jump.tlog", lambda i: i * 10 + (5 * 3600 * 1000 if i >= 300 else 0)
    )
    with caplog.at_level(logging.WARNING, logger="motionbase"):
        times, fresh = _replay_times(log)
    span = times[-1] - times[0]
    assert 6.0 + MAX_LOG_GAP_S - 0.1 < span < 6.0 + MAX_LOG_GAP_S + 0.1, span
    assert 580 <= fresh <= 600 + 50 + 5  # the samples, and holds up to the 0.5 s timeout
    assert any("jumps ahead by more than" in r.getMessage() for r in caplog.records)


def test_one_sample_behind_the_vehicle_clock_is_an_outlier_not_a_reboot(tmp_path):
    """One pair in fifty 3 s behind (a glitch): each was taken for a reboot, which shifted
    the rest of the log 3 s later and stalled it (a 6 s log ran over 25 s, most of it
    stale). A real reboot (the boot time going back and on from there) still re-anchors."""
    glitch = _crafted_tlog(
        tmp_path / "glitch.tlog", lambda i: max(0, i * 10 - 3000) if i % 50 == 25 else i * 10
    )
    times, fresh = _replay_times(glitch)
    assert times[-1] - times[0] == pytest.approx(5.99, abs=0.02) and fresh == len(times)
    reboot = _crafted_tlog(  # boots again at pair 300: its clock starts over from 0
        tmp_path / "reboot.tlog", lambda i: i * 10 if i < 300 else (i - 300) * 10
    )
    times, fresh = _replay_times(reboot)
    assert times[-1] - times[0] == pytest.approx(5.99, abs=0.05)


def test_a_late_burst_of_old_samples_is_dropped_not_taken_for_a_reboot(tmp_path):
    """Five pairs 1.4 s behind the clock and going on (a ground station's late burst of old
    messages, as vtol.tlog has at 611.9 s): the second was taken for a reboot, the rest of
    the log shifted 1.4 s later (a 6 s log replayed as 7.4 s, the inserted gap stale: the
    platform faded) and the old values fed in as new. They are dropped and counted."""
    burst = range(300, 305)

    def values(i: int) -> tuple[tuple[float, ...], tuple[float, ...]]:
        return ((3.0, 0.0, -G), (0.5, 0.0, 0.0)) if i in burst else imu_values(i)

    log = _crafted_tlog(
        tmp_path / "burst.tlog", lambda i: (i - 140) * 10 if i in burst else i * 10, values=values
    )
    with MavlinkSource(str(log), rate_hz=100.0, realtime=False) as src:
        rows = [(s.t, src.fresh, s.specific_force[0]) for s in src]
        stats = src.stats
    times, fresh, fx = np.array(rows).T
    assert times[-1] - times[0] == pytest.approx(5.99, abs=0.02)
    assert fresh.all() and np.abs(fx).max() < 1.0
    assert stats.rejected_invalid == 2 * len(burst)


def _replay_samples(path: Path, n: int = 600) -> tuple[np.ndarray, np.ndarray, Any]:
    """Replay a crafted log at 100 Hz: each tick's time and the index of the pair whose
    specific force it holds (-1: a stale tick, or values not of ``imu_values``), and the
    stats."""
    table = {f32(imu_values(i)[0]): i for i in range(n)}
    with MavlinkSource(str(path), rate_hz=100.0, realtime=False) as src:
        rows = [(s.t, table.get(f32(s.specific_force), -1) if src.fresh else -1) for s in src]
        stats = src.stats
    times, index = np.array(rows).T
    return times, index.astype(int), stats


def _marked(
    outliers: Iterable[int],
) -> Callable[[int], tuple[tuple[float, ...], tuple[float, ...]]]:
    """Crafted pairs' values: those of ``imu_values``, but 3 m/s^2 and 0.5 rad/s to the
    side for the ``outliers`` (not meant to reach a state)."""
    marked = set(outliers)
    return lambda i: ((3.0, 0.0, -G), (0.5, 0.0, 0.0)) if i in marked else imu_values(i)


def test_one_sample_stamped_seconds_ahead_is_an_outlier_not_a_jump(tmp_path):
    """One pair stamped 5 s ahead mid-log (a corrupt time): the clock jumped 5 s with it, the
    good samples after it were behind and dropped for REBOOT_S until re-anchored, so a 6 s
    log replayed as 11 s, 1 s of it lost and 5 s of it stale (the platform faded). That
    one pair is dropped and counted, every other sample replays on time."""
    log = _crafted_tlog(
        tmp_path / "ahead.tlog", lambda i: i * 10 + 5000 * (i == 300), values=_marked([300])
    )
    times, index, stats = _replay_samples(log)
    assert times[-1] - times[0] == pytest.approx(5.99, abs=0.02)
    assert (index >= 0).all()  # every tick fresh, each with a pair of the log's own values
    assert set(index) == set(range(600)) - {300}  # all but the outlier reach a state
    assert stats.rejected_invalid == 2  # its IMU and attitude messages


@pytest.mark.parametrize("second", [5000, 2000], ids=["the same jump", "unrelated times"])
def test_two_samples_in_a_row_far_ahead(tmp_path, second):
    """Pairs 300 and 301 both stamped ahead of where they belong (bad values). Both 5 s: the
    second confirms the first, so they are taken for a jump (the clock goes 5 s ahead,
    pair 301 is used, and the good samples, behind it, are dropped for REBOOT_S, then
    re-anchored as a reboot: the old trade-off, 1 s lost). 5 s then 2 s: the second is
    more than 1 s before the first, both are outliers and only they are lost (the clock used
    to jump with them: 11 s). Either way time never goes back and no older
    sample is fed in after a newer one."""
    ahead = {300: 5000, 301: second}  # (ms ahead of where each pair belongs)
    log = _crafted_tlog(
        tmp_path / "two.tlog", lambda i: i * 10 + ahead.get(i, 0), values=_marked(ahead)
    )
    times, index, stats = _replay_samples(log)
    assert (np.diff(times) > 0).all()
    fresh = index[index >= 0]
    assert (np.diff(fresh) >= 0).all()  # never an older pair after a newer one
    if second < 4000:
        assert times[-1] - times[0] == pytest.approx(5.99, abs=0.02) and (index >= 0).all()
        assert set(index) == set(range(600)) - {300, 301}
        assert stats.rejected_invalid == 4
    else:  # a jump: 5 s more, held stale; pair 300 lost, 301 taken, 302 on behind, dropped
        assert times[-1] - times[0] == pytest.approx(5.99 + 5.0, abs=0.05)
        behind = round(REBOOT_S / 0.01)  # pairs, until they are a reboot
        assert not set(fresh) & set(range(300, 302 + behind))
        assert len(set(fresh) & set(range(302 + behind, 600))) > 0.9 * (600 - 302 - behind)
        assert 5.0 + REBOOT_S - 0.6 < (index < 0).sum() / 100.0 < 5.0 + REBOOT_S + 0.05
        assert stats.rejected_invalid == 2 + 2 * behind


def test_a_genuine_gap_of_seconds_still_replays_as_a_gap(tmp_path):
    """3 s with no sample (a radio dropout): the first sample after it is held back until
    the next confirms the jump (that one is lost), and the gap is held stale for its 3 s."""
    log = _crafted_tlog(tmp_path / "gap.tlog", lambda i: i * 10 + 3000 * (i >= 300))
    times, index, stats = _replay_samples(log)
    assert times[-1] - times[0] == pytest.approx(8.99, abs=0.02)
    assert set(index[index >= 0]) == set(range(600)) - {300}
    stale = (index < 0).sum() / 100.0
    assert 3.0 - 0.6 < stale < 3.0 + 0.05  # the gap, less the 0.5 s the last state is held
    assert stats.rejected_invalid == 2


def test_a_log_whose_boot_times_are_all_zero_is_timed_by_its_receive_times(tmp_path):
    """A sender that leaves time_boot_ms and time_usec at 0 (not filled in): every sample
    had the same time, and the 6 s log replayed as one tick. It falls back to the ground
    station's receive times (10 ms apart here)."""
    log = _crafted_tlog(tmp_path / "zero.tlog", lambda i: 0)
    times, fresh = _replay_times(log)
    assert times[-1] - times[0] == pytest.approx(5.99, abs=0.02) and fresh == len(times)


@pytest.mark.parametrize("compid", [None, 1])
def test_another_component_with_its_own_boot_time_leaves_the_vehicle_clock_alone(tmp_path, compid):
    """A gimbal of the vehicle's system sending ATTITUDE on its own clock (booted an hour
    earlier): the log's clock took every component's time, jumped an hour ahead and back at
    each of its messages, and a 6 s log replayed as 20 minutes, 95 % of it stale, even with
    ``compid`` 1 (which keeps the gimbal's values out). One component's clock times it."""
    log = _crafted_tlog(
        tmp_path / "gimbal.tlog", lambda i: i * 10, gimbal_ms_of=lambda i: 3_600_000 + i * 10
    )
    times, fresh = _replay_times(log, compid)
    assert times[-1] - times[0] == pytest.approx(5.99, abs=0.02) and fresh == len(times)


def test_a_gimbal_heard_first_does_not_take_the_vehicle_clock(tmp_path):
    """No compid, and the log begins with a gimbal's ATTITUDE, sent once a second on its own
    boot clock: the clock was the gimbal's (the first component of the system to give a
    time), so the autopilot's 100 samples a second all took the gimbal's last time, and the
    6 s log replayed as 5 s, half of its ticks stale. The clock is the autopilot's, the
    component whose IMU samples come."""
    log = _crafted_tlog(
        tmp_path / "gimbal_first.tlog",
        lambda i: i * 10,
        gimbal_ms_of=lambda i: 3_600_000 + i * 10 if i % 100 == 0 else None,
    )
    times, fresh = _replay_times(log)
    assert times[-1] - times[0] == pytest.approx(5.99, abs=0.02) and fresh == len(times)


def _crafted_bin(
    path: Path, times_us: list[int], att: tuple[str, str] = ("Qfff", "TimeUS,Roll,Pitch,Yaw")
) -> Path:
    """A DataFlash log of IMU and ATT records stamped ``times_us`` (its FMT records first);
    ``att``: the ATT record's FMT format and columns (its values 2, 1 and 30 deg, packed
    by that format)."""

    def fmt(typ: int, name: str, form: str, columns: str) -> bytes:
        sizes = {"Q": 8, "f": 4, "B": 1, "n": 4, "N": 16, "Z": 64}
        length = 3 + sum(sizes[c] for c in form)
        body = struct.pack(
            "<BB4s16s64s", typ, length, name.encode(), form.encode(), columns.encode()
        )
        return b"\xa3\x95\x80" + body

    out = bytearray(fmt(128, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns"))
    out += fmt(129, "IMU", "QffffffB", "TimeUS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,I")
    out += fmt(130, "ATT", *att)
    roll = b"2" if att[0][1] == "N" else 2.0  # (a 16-character text column: "2")
    for t in times_us:
        out += b"\xa3\x95\x81" + struct.pack("<QffffffB", t, 0.01, 0.0, 0.0, 0.1, 0.0, -9.8, 0)
        out += b"\xa3\x95\x82" + struct.pack("<" + att[0].replace("N", "16s"), t, roll, 1.0, 30.0)
    path.write_bytes(bytes(out))
    return path


def test_a_dataflash_log_whose_clock_jumps_hours_ahead_holds_the_gap_briefly(tmp_path):
    """The same 5-hour jump in a DataFlash .bin: only the .tlog's clock shortened gaps, so the
    .bin replayed 18,006 s of ticks (5 hours in real time, all but 650 of them stale)."""
    times = [10_000_000 + i * 10_000 + (5 * 3600 * 10**6 if i >= 300 else 0) for i in range(600)]
    times, fresh = _replay_times(_crafted_bin(tmp_path / "jump.bin", times))
    span = times[-1] - times[0]
    assert 6.0 + MAX_LOG_GAP_S - 0.1 < span < 6.0 + MAX_LOG_GAP_S + 0.1, span
    assert 580 <= fresh <= 600 + 50 + 5


@pytest.mark.parametrize("reboot", [False, True], ids=["then on", "then a reboot"])
def test_a_dataflash_record_stamped_seconds_ahead_is_an_outlier(tmp_path, reboot):
    """A .bin whose IMU and ATT records 300 are stamped 5 s ahead: the clock jumped with them,
    and the 6 s log replayed as 11 s (1 s of its records dropped, 5 s stale). They alone are
    dropped. Followed by a reboot (the boot time starting over), the reboot re-anchors the
    clock where the log was before them, not 5 s later: 3 s, 1 s held while the records
    after it go on for REBOOT_S (dropped), then their last 2 s."""
    times = [
        10_000_000 + i * 10_000 + 5 * 10**6 * (i == 300)
        if i <= 300 or not reboot
        else 100_000 + (i - 301) * 10_000
        for i in range(600)
    ]
    with MavlinkSource(str(_crafted_bin(tmp_path / "ahead.bin", times)), realtime=False) as src:
        rows = [(s.t, src.fresh) for s in src]
        stats = src.stats
    t, fresh = np.array(rows).T
    if not reboot:
        assert t[-1] - t[0] == pytest.approx(5.99, abs=0.03) and fresh.all()
        assert stats.rejected_invalid == 2
    else:
        assert t[-1] - t[0] == pytest.approx(2.99 + 2.98, abs=0.03)
        assert fresh.mean() > (5.97 - REBOOT_S) / 5.97 - 0.02
        behind = round(REBOOT_S / 0.01)  # record pairs, until a reboot (one more: rounding)
        assert 2 + 2 * behind <= stats.rejected_invalid <= 2 + 2 * (behind + 1)


@pytest.mark.parametrize(
    "att",
    [("Qfff", "TimeUS,Rol,Pitch,Yaw"), ("QNff", "TimeUS,Roll,Pitch,Yaw")],
    ids=["a column renamed", "a text column"],
)
def test_a_dataflash_log_whose_att_format_is_damaged_is_rejected_not_a_traceback(att, tmp_path):
    """A DataFlash log whose ATT FMT record is damaged (its Roll column renamed, or made
    text): each ATT record is invalid input, rejected and counted, and the stream goes on
    (the attitude never fresh: the platform stays at neutral) to the end of the log, exit
    0. The first one used to end the run (parked) with an AttributeError or TypeError
    traceback, exit status 1, a damaged file taken for a bug."""
    times = [10_000_000 + i * 10_000 for i in range(300)]
    log = _crafted_bin(tmp_path / "damaged.bin", times, att=att)
    out = tmp_path / "run.mcap"
    cmd = [sys.executable, "-m", "motionbase", "stream", "--mavlink", str(log), "--fast"]
    done = subprocess.run(cmd + ["--out", str(out)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr
    assert "stopped by end of source" in done.stdout
    assert "invalid 300)" in done.stdout  # every ATT record
    msgs = read_messages(out)
    assert msgs["/platform/pose"][-1]["phase"] == "parked"
    assert not any(m["fresh"] for m in msgs["/aircraft/state"])  # no attitude: all stale


# --------------------------------------------------------------------------- real logs


def body_down(attitude: np.ndarray) -> np.ndarray:
    """Unit vector of gravity (NED down) in body axes for Z-Y-X Euler angles."""
    r = Rotation.from_euler("ZYX", attitude[::-1])
    return r.inv().apply([0.0, 0.0, 1.0])


@pytest.mark.parametrize("name", [TLOG, BIN])
def test_real_logs_give_plausible_states(name: str, flight_data: Path) -> None:
    with MavlinkSource(str(flight_data / name), rate_hz=50.0, realtime=False) as src:
        rows = [(s, src.fresh, s.t) for s in src]
        stats = src.stats
    span, behind, ahead = _log_span_and_out_of_order(flight_data / name)
    # the replay lasts as long as the log's vehicle clock; its samples out of order (vtol.tlog:
    # four, 1.4 s behind at 611.9 s) are dropped, not taken for a reboot that shifted the rest,
    # and so is the first sample after each radio dropout (vtol.tlog: four, 1.5 to 3 s long)
    assert rows[-1][2] - rows[0][2] == pytest.approx(span, abs=0.05)
    states = [s for s, fresh, _ in rows if fresh]
    assert len(rows) > 5000 and len(states) > 0.9 * len(rows)
    assert all(s.is_finite() for s, _, _ in rows)
    f = np.array([s.specific_force for s in states])
    w = np.array([s.angular_velocity for s in states])
    att = np.array([s.attitude for s in states])
    # an aeroplane in flight: |f| near g on average, rates and angles bounded
    assert 0.9 * G < np.linalg.norm(f, axis=1).mean() < 1.2 * G
    assert np.abs(w).max() < 10.0
    assert np.abs(att[:, 0]).max() <= math.pi and np.abs(att[:, 1]).max() <= math.pi / 2
    assert np.all((-math.pi <= att[:, 2]) & (att[:, 2] < math.pi))
    # sign convention, checked against the log's own attitude: the accelerometer
    # reads minus gravity in body axes (level: f_z ~ -g), so f points "up"
    level = (np.abs(att[:, :2]).max(axis=1) < math.radians(5)) & (np.linalg.norm(w, axis=1) < 0.1)
    assert level.sum() > 500
    assert abs(np.median(np.linalg.norm(f[level], axis=1)) - G) < 0.8
    assert np.median(f[level, 2]) < -0.9 * G
    down = np.array([body_down(a) for a in att])
    cos = -np.sum(f * down, axis=1) / np.linalg.norm(f, axis=1)
    assert np.median(np.degrees(np.arccos(np.clip(cos[level], -1, 1)))) < 3.0
    assert np.median(np.degrees(np.arccos(np.clip(cos, -1, 1)))) < 15.0
    assert stats.rejected == behind + ahead and stats.used > 1000
    assert isinstance(stats, MavlinkStats)


def _log_span_and_out_of_order(path: Path) -> tuple[float, int, int]:
    """A real log's IMU and attitude samples read with pymavlink alone: the span of their
    vehicle times (s), and how many lie more than 1 s behind, and ahead of, the latest before
    them (these real logs have no lone outlier ahead: each is the first after a gap)."""
    conn = mavutil.mavlink_connection(str(path))
    types = ["IMU", "ATT", "ATTITUDE", "HIGHRES_IMU", "SCALED_IMU", "SCALED_IMU2", "RAW_IMU"]
    first, latest, behind, ahead = None, -math.inf, 0, 0
    while (msg := conn.recv_match(type=types)) is not None:
        for field, scale in (("TimeMS", 1e-3), ("TimeUS", 1e-6), ("time_boot_ms", 1e-3)):
            if hasattr(msg, field):
                t = getattr(msg, field) * scale
                break
        else:
            t = msg.time_usec * 1e-6
        first = t if first is None else first
        behind += t < latest - 1.0
        ahead += math.isfinite(latest) and t > latest + 1.0
        latest = max(latest, t)
    return latest - first, behind, ahead


def test_log_duration_and_tick_clock(flight_data: Path) -> None:
    with MavlinkSource(str(flight_data / BIN), rate_hz=40.0, realtime=False, duration_s=5.0) as src:
        ts = [s.t for s in src]
    assert len(ts) == 200
    np.testing.assert_allclose(ts, np.arange(200) / 40.0)


def test_a_log_cut_to_its_first_bytes_is_a_clear_error(flight_data: Path, tmp_path: Path) -> None:
    """The first 100 bytes of a real .tlog (a copy cut short): pymavlink fails inside its
    parser; the message says the file is not a whole log, not "check the connection string"."""
    cut = tmp_path / "cut.tlog"
    cut.write_bytes((flight_data / TLOG).read_bytes()[:100])
    with pytest.raises(SourceError) as err:
        MavlinkSource(str(cut)).open()
    message = str(err.value)
    assert message.startswith(f"mavlink log {cut}: cannot read it as a MAVLink log (")
    assert message.endswith("is it a whole telemetry .tlog or DataFlash .bin?")
    assert "connection string" not in message and "\n" not in message


@pytest.mark.parametrize(
    ("name", "renamed", "hint"), [(BIN, "flight.tlog", ".bin"), (TLOG, "a.BIN", ".tlog")]
)
def test_a_log_named_for_the_other_format_is_told_its_name(
    name, renamed, hint, flight_data, tmp_path
):
    """A DataFlash log named .tlog (or a .tlog named .BIN): pymavlink reads a file by its
    name, finds no messages, and the line asked "is it a telemetry .tlog or a DataFlash .bin
    with IMU and ATT?", which it is. The line says which it is and the name to give it."""
    log = tmp_path / renamed
    log.write_bytes((flight_data / name).read_bytes())
    cmd = [sys.executable, "-m", "motionbase", "stream", "--mavlink", str(log), "--fast"]
    done = subprocess.run(
        cmd + ["--out", str(tmp_path / "o.mcap")], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert done.stderr.rstrip().endswith(f"give it a name ending in {hint}"), done.stderr


# --------------------------------------------------------------------------- misuse


def test_clear_errors_for_misuse(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="rate_hz"):
        MavlinkSource(rate_hz=0)
    with pytest.raises(ConfigError, match="sysid"):
        MavlinkSource(sysid=0)
    with pytest.raises(ConfigError, match="compid: must be a component id 1..255, got 300; leave"):
        MavlinkSource(compid=300)
    with pytest.raises(ConfigError, match="stale_timeout_s"):
        MavlinkSource(stale_timeout_s=math.nan)
    with pytest.raises(SourceError, match="no such file"):
        MavlinkSource(str(tmp_path / "missing.tlog")).open()
    with pytest.raises(SourceError, match="not open"):
        iter(MavlinkSource(str(TLOG)))
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as taken:  # (a ground station's)
        taken.bind(("127.0.0.1", 0))
        url = f"udpin:127.0.0.1:{taken.getsockname()[1]}"
        with pytest.raises(SourceError, match="in use.*another program listens there"):
            MavlinkSource(url).open()
    d = MavlinkSource().describe()
    assert d["url"] == "udpin:127.0.0.1:14550" and d["signing"] is False
    assert d["mavlink_version"] == "2.0"


def test_a_duration_too_long_to_count_in_ticks_runs_without_an_end() -> None:
    """``stream --duration 1e308``: its ticks (1e308 s times the rate) overflowed to
    infinity and the first tick raised OverflowError, a traceback. It runs until stopped."""
    import itertools

    with MavlinkSource("udpin:127.0.0.1:0", duration_s=1e308, request_streams=False) as src:
        assert len(list(itertools.islice(src, 3))) == 3


def test_a_serial_device_is_a_character_device(tmp_path: Path) -> None:
    """A real pseudo-terminal opens as a serial link and its messages are used; an ordinary
    file not named as a log (once opened as a serial port: nothing, forever) is refused, and
    so is a string of an unknown kind (once a ValueError from pymavlink's UDP parser)."""
    import os
    import pty

    master, slave = pty.openpty()
    stop = threading.Event()

    class Pty:
        def write(self, data: bytes) -> None:
            os.write(master, data)

    mav = ML.MAVLink(Pty(), srcSystem=1, srcComponent=1)
    try:
        with MavlinkSource(
            os.ttyname(slave), rate_hz=50.0, duration_s=1.0, request_streams=False
        ) as src:
            th = threading.Thread(target=send_loop, args=(mav, send_good, [], 50.0, None, stop))
            th.start()
            try:
                fresh = [src.fresh for _ in src]
            finally:
                stop.set()
                th.join(timeout=5)
    finally:
        os.close(master)
        os.close(slave)
    assert sum(fresh) > 10 and src.stats.used > 20 and src.stats.rejected == 0

    notes = tmp_path / "empty.toml"
    notes.write_text("")
    with pytest.raises(ConfigError, match=r"empty\.toml: neither a MAVLink log") as err:
        MavlinkSource(str(notes))
    assert ".tlog" in str(err.value) and "character device" in str(err.value)
    with pytest.raises(ConfigError, match=r"foo:bar: unknown kind of link 'foo'; give udpin:"):
        MavlinkSource("foo:bar")


class _TcpWire:
    """A file-like sink for pymavlink's encoder: what it writes goes down a TCP socket."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock

    def write(self, data: bytes) -> None:
        self.sock.sendall(bytes(data))


def test_a_tcp_peer_that_closes_ends_the_run_with_one_error(capfd):
    """SITL (or anything at the other end of tcp:) closing its side of the connection: pymavlink
    printed "EOF on TCP socket" at every read (about 100,000 lines a second on stdout) and the
    source read the dead link for ever, every tick stale. It is a failed link now, as a reset
    already was: one SourceError, which parks the platform."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    port = server.getsockname()[1]
    try:
        with MavlinkSource(f"tcp:127.0.0.1:{port}", rate_hz=100.0) as src:
            peer, _ = server.accept()
            mav = ML.MAVLink(_TcpWire(peer), srcSystem=1, srcComponent=1)
            it = iter(src)
            for i in range(5):
                send_good(mav, i)
                next(it)
            peer.shutdown(socket.SHUT_WR)  # the peer is done sending (it still reads)
            t0 = time.monotonic()
            with pytest.raises(SourceError, match="the peer closed the connection"):
                while time.monotonic() - t0 < 30.0:  # (a watchdog, not a bound)
                    next(it)
            peer.close()
    finally:
        server.close()
    assert "EOF on TCP socket" not in capfd.readouterr().out


def test_tcpin_listens_again_when_its_peer_stops_sending():
    """tcpin: a sender that closes its sending side and stays connected (it still reads our
    heartbeats): pymavlink went on reading the finished connection for ever, never taking a
    new one, so a restarted sender could not get in. The finished connection is dropped at
    its end and the next one is taken."""
    probe = socket.socket()
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()

    def connect_and_send(first: int) -> socket.socket:
        sock = socket.create_connection(("127.0.0.1", port))
        mav = ML.MAVLink(_TcpWire(sock), srcSystem=1, srcComponent=1)
        for i in range(first, first + 5):
            send_good(mav, i)
        return sock

    with MavlinkSource(f"tcpin:127.0.0.1:{port}", rate_hz=100.0, stale_timeout_s=0.1) as src:
        it = iter(src)
        first = connect_and_send(0)
        first.shutdown(socket.SHUT_WR)
        for _ in range(20):
            next(it)
        used = src.stats.used
        second = connect_and_send(100)
        fresh = False
        t0 = time.monotonic()
        while not fresh and time.monotonic() - t0 < 30.0:  # (a watchdog, not a bound)
            next(it)
            fresh = src.fresh
        first.close()
        second.close()
    assert used == 10 and fresh


def test_a_refusal_meant_for_another_ground_station_does_not_stop_the_stream_requests(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A COMMAND_ACK refusing SET_MESSAGE_INTERVAL that answers someone else (another ground
    station behind the same router, target_system 42) before we asked anything: it was taken
    for the vehicle's answer to us, warned of as a refusal, and no request was ever sent, so
    a silent vehicle that would have streamed stayed silent (every tick stale). Only an answer
    to our own outstanding request counts."""
    caplog.set_level(logging.WARNING, logger="motionbase")
    stop = threading.Event()
    got: list[Any] = []
    with MavlinkSource(
        "udpin:127.0.0.1:0", rate_hz=50.0, duration_s=2.4, request_timeout_s=0.8
    ) as src:
        foreign = mavutil.mavlink_connection(
            f"udpout:127.0.0.1:{src.local_address[1]}", source_system=1, source_component=1
        )
        it = iter(src)
        next(it)
        foreign.mav.command_ack_send(
            ML.MAV_CMD_SET_MESSAGE_INTERVAL, ML.MAV_RESULT_DENIED, 0, 0, 42, 190
        )
        foreign.close()
        th = threading.Thread(
            target=_vehicle, args=(src.local_address[1],), kwargs=dict(ack=True, stop=stop, got=got)
        )
        th.start()
        try:
            fresh = False
            for _ in it:
                fresh = src.fresh
        finally:
            stop.set()
            th.join(timeout=5)
    assert fresh
    assert not any("refused MAV_CMD_SET_MESSAGE_INTERVAL" in r.message for r in caplog.records)


def test_udpin_answers_its_vehicle_not_every_address_that_ever_sent_a_datagram():
    """pymavlink's udpin sends each message to every address a datagram ever came from, for
    ever: 200 strangers (one datagram of garbage each, as spoofed sources would send) got our
    heartbeat every second, and the tick that sends it spent a sendto on each (a reflector,
    and a stall that grows with the flood). Our messages go to the vehicle's address now."""
    strangers = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(200)]
    vehicle = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        with MavlinkSource("udpin:127.0.0.1:0", rate_hz=100.0) as src:
            it = iter(src)
            for s in strangers:
                s.sendto(b"\xfd garbage", src.local_address)
                s.setblocking(False)
            mav = ML.MAVLink(_UdpWire(vehicle, src.local_address), srcSystem=1, srcComponent=1)
            mav.heartbeat_send(ML.MAV_TYPE_FIXED_WING, ML.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 0)
            for _ in range(120):  # 1.2 s: one heartbeat of ours at least
                next(it)
        reached = 0
        for s in strangers:
            with contextlib.suppress(BlockingIOError):
                s.recv(1000)
                reached += 1
        vehicle.setblocking(False)
        heard = vehicle.recv(1000)
    finally:
        for s in (*strangers, vehicle):
            s.close()
    assert reached == 0 and heard


class _UdpWire:
    """A file-like sink for pymavlink's encoder: each message one datagram to ``addr``."""

    def __init__(self, sock: socket.socket, addr: tuple[str, int]) -> None:
        self.sock, self.addr = sock, addr

    def write(self, data: bytes) -> None:
        self.sock.sendto(bytes(data), self.addr)


@pytest.mark.parametrize("url", ["udpin:[::1]:14550", "tcp:[::1]:5760", "udpout:::1:14550"])
def test_an_ipv6_address_is_named_as_such(url: str) -> None:
    """pymavlink opens IPv4 sockets only: ``udpin:[::1]:14550`` said "host name '[::1]' does
    not resolve", which sends the user to check a spelling that is right."""
    with pytest.raises(ConfigError, match="IPv4 only") as err:
        MavlinkSource(url).open()
    assert "does not resolve" not in str(err.value)
