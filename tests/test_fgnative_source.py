"""FlightGear native-FDM source: real JSBSim packets, crafted packets, watchdog, bad input.

The main test runs the real ``jsbsim`` package with a ``FLIGHTGEAR`` UDP output
directive to the source and compares every received sample with what
:class:`JsbsimSource` reads from the same script (same aircraft, same times), to
the precision of the packet's 32-bit floats. Crafted packets are built here from
the documented layout of ``FGNetFDM`` (``net_fdm.hxx``), not with the module.
"""

from __future__ import annotations

import logging
import math
import os
import socket
import struct
import threading
import time
from pathlib import Path

import jsbsim
import numpy as np
import pytest

from motionbase.cli import main
from motionbase.errors import ConfigError, SourceError
from motionbase.io.fgnative_source import FgNativeSource, decode_fgnetfdm
from motionbase.io.jsbsim_source import JsbsimSource
from motionbase.io.live_source import MIN_READS
from motionbase.io.mcap_source import McapSource, read_messages

G0 = 9.80665
EPS32 = 2.0**-24  # relative rounding error of a double stored as a float32
FT = 0.3048
DATA = Path(__file__).parent / "data"

# FGNetFDM, from the field list of net_fdm.hxx (FlightGear and JSBSim), in order:
# (name, struct code, count). Version 25 adds the tank block marked below.
_COMMON_HEAD = [
    ("version", "I", 1),
    ("padding", "I", 1),
    ("longitude", "d", 1),
    ("latitude", "d", 1),
    ("altitude", "d", 1),
    ("agl", "f", 1),
    ("phi", "f", 1),
    ("theta", "f", 1),
    ("psi", "f", 1),
    ("alpha", "f", 1),
    ("beta", "f", 1),
    ("phidot", "f", 1),
    ("thetadot", "f", 1),
    ("psidot", "f", 1),
    ("vcas", "f", 1),
    ("climb_rate", "f", 1),
    ("v_north", "f", 1),
    ("v_east", "f", 1),
    ("v_down", "f", 1),
    ("v_body_u", "f", 1),
    ("v_body_v", "f", 1),
    ("v_body_w", "f", 1),
    ("A_X_pilot", "f", 1),
    ("A_Y_pilot", "f", 1),
    ("A_Z_pilot", "f", 1),
    ("stall_warning", "f", 1),
    ("slip_deg", "f", 1),
    ("num_engines", "I", 1),
    ("eng_state", "I", 4),
    ("rpm", "f", 4),
    ("fuel_flow", "f", 4),
    ("fuel_px", "f", 4),
    ("egt", "f", 4),
    ("cht", "f", 4),
    ("mp_osi", "f", 4),
    ("tit", "f", 4),
    ("oil_temp", "f", 4),
    ("oil_px", "f", 4),
    ("num_tanks", "I", 1),
    ("fuel_quantity", "f", 4),
]
_V25_TANKS = [
    ("tank_selected", "I", 4),
    ("capacity_m3", "d", 4),
    ("unusable_m3", "d", 4),
    ("density_kgpm3", "d", 4),
    ("level_m3", "d", 4),
]
_COMMON_TAIL = [
    ("num_wheels", "I", 1),
    ("wow", "I", 3),
    ("gear_pos", "f", 3),
    ("gear_steer", "f", 3),
    ("gear_compression", "f", 3),
    ("cur_time", "I", 1),
    ("warp", "i", 1),
    ("visibility", "f", 1),
    ("elevator", "f", 1),
    ("elevator_trim_tab", "f", 1),
    ("left_flap", "f", 1),
    ("right_flap", "f", 1),
    ("left_aileron", "f", 1),
    ("right_aileron", "f", 1),
    ("rudder", "f", 1),
    ("nose_wheel", "f", 1),
    ("speedbrake", "f", 1),
    ("spoilers", "f", 1),
]


def fgnetfdm_packet(version: int = 24, **fields: float) -> bytes:
    """One FGNetFDM datagram, network byte order, the given fields set, the others 0."""
    layout = _COMMON_HEAD + (_V25_TANKS if version == 25 else []) + _COMMON_TAIL
    fmt = ">" + "".join(f"{n}{code}" for _, code, n in layout)
    values: list[float] = []
    for name, _code, n in layout:
        v = version if name == "version" else fields.get(name, 0)
        values.extend([v] * n if n > 1 else [v])
    return struct.pack(fmt, *values)


def euler_rates(p, q, r, phi, theta):
    """Z-Y-X Euler angle rates from body rates (the forward kinematics, as JSBSim computes)."""
    thetadot = q * math.cos(phi) - r * math.sin(phi)
    psidot = (q * math.sin(phi) + r * math.cos(phi)) / math.cos(theta)
    phidot = p + psidot * math.sin(theta)
    return phidot, thetadot, psidot


def wrap(a):
    return (a + math.pi) % (2 * math.pi) - math.pi


@pytest.fixture
def sender():
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    yield s
    s.close()


def _output_directive(tmp_path: Path, port: int, rate_hz: float) -> Path:
    xml = tmp_path / "fg_output.xml"
    xml.write_text(
        '<?xml version="1.0"?>\n'
        f'<output name="127.0.0.1" type="FLIGHTGEAR" protocol="UDP" port="{port}" '
        f'rate="{rate_hz}"/>\n'
    )
    return xml


@pytest.mark.parametrize("script", ["c1723", "737_cruise_steady_turn"])
def test_real_jsbsim_packets_equal_the_jsbsim_source(tmp_path, script):
    """JSBSim's own FLIGHTGEAR output, received live, equals JsbsimSource sample for sample."""
    reference = list(JsbsimSource(script, duration_s=2.0))
    rate_hz = 1.0 / (reference[1].t - reference[0].t)
    root = jsbsim.get_default_root_dir()
    with FgNativeSource("fgnative:udp:127.0.0.1:0", rate_hz=rate_hz) as src:
        port = src.local_address[1]
        fdm = jsbsim.FGFDMExec(root, None)
        fdm.set_debug_level(0)
        fdm.set_output_path(str(tmp_path))
        assert fdm.load_script(os.path.join(root, "scripts", f"{script}.xml"))
        assert fdm.set_output_directive(str(_output_directive(tmp_path, port, rate_hz)))
        assert fdm.run_ic()
        it = iter(src)
        got = []
        for _ in reference:
            assert fdm.run()  # sends one datagram (the output runs every step at this rate)
            state = next(it)
            assert src.tick.new_sample and src.fresh
            got.append(state)
        stats = src.stats
    assert stats.bad_data == 0 and stats.rejected_invalid == 0
    assert stats.extra["versions"] == "24"
    euler_discrepancy = 0.0
    for s, r in zip(got, reference, strict=True):
        f_ref, w_ref, att_ref = r.specific_force, r.angular_velocity, r.attitude
        # specific force and angles: one float32 rounding of the sent value
        np.testing.assert_array_less(
            np.abs(s.specific_force - f_ref), EPS32 * np.abs(f_ref) + 1e-12
        )
        np.testing.assert_array_less(
            np.abs(s.attitude[:2] - att_ref[:2]), EPS32 * np.abs(att_ref[:2]) + 1e-12
        )
        assert abs(wrap(s.attitude[2] - att_ref[2])) <= EPS32 * abs(att_ref[2]) + 1e-12
        assert -math.pi <= s.attitude[2] < math.pi
        # body rates come back from float32 Euler rates and angles: propagate the roundings
        phi, theta = att_ref[0], att_ref[1]
        rates = euler_rates(*w_ref, phi, theta)
        tol = EPS32 * sum(abs(x) for x in rates) * (1 + abs(phi) + abs(theta)) * 1.01 + 1e-12
        np.testing.assert_array_less(np.abs(s.angular_velocity - w_ref), tol)
        euler_discrepancy = max(euler_discrepancy, float(np.max(np.abs(np.array(rates) - w_ref))))
    if script == "c1723":
        # on the runway, brakes set: an accelerometer reads -g along z (specific force, FRD)
        for s in got[-60:]:
            assert -10.3 < s.specific_force[2] < -9.3
            assert abs(s.specific_force[0]) < 1.0 and abs(s.specific_force[1]) < 1.0
    else:
        # banked turn: the Euler rates differ from the body rates far beyond the tolerance,
        # so the comparison above checks that the source converts them
        assert euler_discrepancy > 1e-3


def test_crafted_version_25_packet(sender):
    """A version-25 datagram (longer tank block) gives the documented fields, in SI and FRD."""
    p, q, r, phi, theta, psi = 0.1, -0.2, 0.3, 0.4, -0.3, 4.0
    phidot, thetadot, psidot = euler_rates(p, q, r, phi, theta)
    packet = fgnetfdm_packet(
        25,
        phi=phi,
        theta=theta,
        psi=psi,
        phidot=phidot,
        thetadot=thetadot,
        psidot=psidot,
        A_X_pilot=3.0,
        A_Y_pilot=-1.0,
        A_Z_pilot=-G0 / FT,
    )
    assert len(packet) == 552
    with FgNativeSource("fgnative:udp:127.0.0.1:0", rate_hz=100) as src:
        sender.sendto(packet, src.local_address)
        state = next(iter(src))
        assert src.fresh
    f32 = lambda x: float(np.float32(x))  # noqa: E731 - the packet's precision
    np.testing.assert_allclose(
        state.specific_force, [3.0 * FT, -1.0 * FT, f32(-G0 / FT) * FT], rtol=1e-7
    )
    assert state.specific_force[2] == pytest.approx(-G0, rel=1e-6)
    np.testing.assert_allclose(state.angular_velocity, [p, q, r], atol=1e-6)
    np.testing.assert_allclose(state.attitude, [phi, theta, psi - 2 * math.pi], atol=1e-6)
    assert src.stats.extra["versions"] == "25"


def test_unknown_version_refused_with_one_warning(sender, caplog):
    packet = bytearray(fgnetfdm_packet(24, A_Z_pilot=-32.0))
    struct.pack_into(">I", packet, 0, 23)  # a version this source does not know
    with caplog.at_level(logging.WARNING, logger="motionbase"):
        with FgNativeSource("fgnative:udp:127.0.0.1:0", rate_hz=100) as src:
            for _ in range(5):
                sender.sendto(bytes(packet), src.local_address)
            it = iter(src)
            state = next(it)
            next(it)
            assert not src.fresh
            stats = src.stats
    assert stats.bad_data == 5 and stats.accepted == 0
    assert stats.extra["refused versions"] == "23"
    assert state.specific_force[2] == pytest.approx(-G0)  # the neutral hold, not the packet
    warnings = [r for r in caplog.records if "version 23" in r.getMessage()]
    assert len(warnings) == 1 and "\n" not in warnings[0].getMessage()


def test_garbage_of_many_versions_is_reported_three_times_at_most(sender, caplog):
    """Garbage on the port reads as a new protocol version in almost every datagram: the
    first three are warned of (the third says the rest are only counted), then silence;
    it was one warning per datagram, without end."""
    packet = bytearray(fgnetfdm_packet(24, A_Z_pilot=-32.0))
    with caplog.at_level(logging.WARNING, logger="motionbase"):
        with FgNativeSource("fgnative:udp:127.0.0.1:0", rate_hz=100) as src:
            for version in range(100, 140):
                struct.pack_into(">I", packet, 0, version)
                sender.sendto(bytes(packet), src.local_address)
            it = iter(src)
            for _ in range(20):
                next(it)
            stats = src.stats
    assert stats.bad_data == 40
    warned = [r.getMessage() for r in caplog.records if "FGNetFDM version" in r.getMessage()]
    assert len(warned) == 3 and "further unknown versions" in warned[-1]
    assert stats.extra["refused versions"] == "100/101/102"


def test_datagrams_too_short_to_be_fgnetfdm_are_named_so_and_leave_the_version_warnings(
    sender, caplog
):
    """A datagram shorter than any FGNetFDM (an empty one, a stray byte, a word of text)
    was refused as "FGNetFDM version -1" (or the version its first four bytes spell), and
    each used up one of the three version warnings. It gets one warning of its own."""
    packet = bytearray(fgnetfdm_packet(24, A_Z_pilot=-32.0))
    with caplog.at_level(logging.WARNING, logger="motionbase"):
        with FgNativeSource("fgnative:udp:127.0.0.1:0", rate_hz=100) as src:
            for short in (b"", b"\x18", b"hello", bytes(407)):
                sender.sendto(short, src.local_address)
            for version in (100, 101, 102, 103):
                struct.pack_into(">I", packet, 0, version)
                sender.sendto(bytes(packet), src.local_address)
            it = iter(src)
            for _ in range(3):
                next(it)
            stats = src.stats
    assert stats.bad_data == 8 and stats.bad_bytes == 0 + 1 + 5 + 407 + 4 * 408
    assert stats.extra["too short"] == 4
    assert stats.extra["refused versions"] == "100/101/102"
    messages = [r.getMessage() for r in caplog.records]
    short = [m for m in messages if "too short" in m]
    assert len(short) == 1 and "0 bytes" in short[0] and "\n" not in short[0]
    assert "version" not in short[0].split("(")[0]  # (it names the sizes of the versions)
    versions = [m for m in messages if "FGNetFDM version" in m]
    assert len(versions) == 3 and "version 100 " in versions[0]


def test_nan_and_infinite_angles_decode_without_numpy_warnings():
    """Non-finite angles are refused after decoding; decoding them printed numpy's two-line
    RuntimeWarnings (their source lines too) on every such datagram."""
    import warnings

    for bad in (math.nan, math.inf):
        packet = fgnetfdm_packet(24, A_Z_pilot=-32.0, phi=bad, theta=bad)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            version, values = decode_fgnetfdm(packet)
        assert version == 24 and values is not None and not math.isfinite(values[3])


def test_wrong_size_and_garbage_are_not_used(sender):
    good = fgnetfdm_packet(24, A_Z_pilot=-32.0)
    with FgNativeSource("fgnative:udp:127.0.0.1:0", rate_hz=100) as src:
        for bad in (good[:-4], good + b"\0\0\0\0", b"hello", b""):
            sender.sendto(bad, src.local_address)
        next(iter(src))
        stats = src.stats
        assert not src.fresh
    assert stats.bad_data == 4 and stats.accepted == 0
    assert stats.extra["wrong size"] == 2


def test_a_known_version_of_the_wrong_size_is_warned_of_once(sender, caplog):
    """A datagram whose version is 24 or 25 but whose size is not that version's was refused
    without a word (only the end-of-run counter "wrong size"): FlightGear's development
    builds of July to October 2020 sent version 24 in the 552-byte layout of 25, and a
    sender that bumps the version without the tank block sends 25 in 408 bytes. The
    platform stayed at neutral and nothing said why. One warning names the size and the
    version's size; the rest are counted."""
    v24_as_25 = bytearray(fgnetfdm_packet(25, A_Z_pilot=-32.0))
    struct.pack_into(">I", v24_as_25, 0, 24)
    v25_as_24 = bytearray(fgnetfdm_packet(24, A_Z_pilot=-32.0))
    struct.pack_into(">I", v25_as_24, 0, 25)
    with caplog.at_level(logging.WARNING, logger="motionbase"):
        with FgNativeSource("fgnative:udp:127.0.0.1:0", rate_hz=100) as src:
            for _ in range(3):
                sender.sendto(bytes(v24_as_25), src.local_address)
                sender.sendto(bytes(v25_as_24), src.local_address)
            it = iter(src)
            next(it)
            next(it)
            assert not src.fresh
            stats = src.stats
    assert stats.bad_data == 6 and stats.accepted == 0 and stats.extra["wrong size"] == 6
    warned = [r.getMessage() for r in caplog.records if "FGNetFDM" in r.getMessage()]
    assert len(warned) == 1 and "\n" not in warned[0]
    assert "552 bytes" in warned[0] and "version 24 is 408 bytes" in warned[0]


def _warnings_after_sending(sender, caplog, forces: list, period_s: float = 0.02) -> list[str]:
    """The source's warnings after ``forces`` (A_X/Y/Z_pilot, ft/s^2) were sent, one packet
    every ``period_s`` s, each taken by the source."""
    with caplog.at_level(logging.WARNING, logger="motionbase"):
        with FgNativeSource("fgnative:udp:127.0.0.1:0", rate_hz=1 / period_s) as src:
            it = iter(src)
            for fx, fy, fz in forces:
                sender.sendto(
                    fgnetfdm_packet(24, A_X_pilot=fx, A_Y_pilot=fy, A_Z_pilot=fz),
                    src.local_address,
                )
                next(it)
    return [r.getMessage() for r in caplog.records if "acceleration" in r.getMessage()]


def test_a_flight_model_that_sends_no_acceleration_is_warned_of_once(sender, caplog):
    """FlightGear's UFO, magic-carpet and null flight models (and JSBSim held down) send
    A_X/Y/Z_pilot = 0: at rest the seat feels 1 g up, so zero is a free fall, and the
    platform cued one, then nothing, without a word. After a second of exact zeros one
    warning names the flight models; a real force, or zeros for half a second (a
    parabola's top), says nothing."""
    warned = _warnings_after_sending(sender, caplog, [(0.0, 0.0, 0.0)] * 80)
    assert len(warned) == 1 and "\n" not in warned[0] and "UFO" in warned[0]
    caplog.clear()
    at_rest = [(0.0, 0.0, -32.17)] * 30
    brief = at_rest + [(0.0, 0.0, 0.0)] * 20 + at_rest + [(0.0, 0.0, 0.0)] * 20
    assert _warnings_after_sending(sender, caplog, brief) == []


@pytest.mark.parametrize(
    "field, value",
    [
        ("A_Z_pilot", float("nan")),
        ("A_X_pilot", float("inf")),
        ("A_Y_pilot", 1e6),  # ~31,000 g
        ("phidot", 1e4),  # rad/s
        ("phi", 4.0),  # beyond pi
        ("theta", 2.0),  # beyond pi/2
        ("psi", float("nan")),
    ],
)
def test_invalid_values_never_reach_the_state(sender, field, value):
    valid = fgnetfdm_packet(24, A_Z_pilot=-32.0, phi=0.1)
    with FgNativeSource("fgnative:udp:127.0.0.1:0", rate_hz=100) as src:
        it = iter(src)
        sender.sendto(valid, src.local_address)
        held = next(it)
        bad = fgnetfdm_packet(24, **{"A_Z_pilot": -32.0, "phi": 0.1, field: value})
        sender.sendto(bad, src.local_address)
        state = next(it)
        stats = src.stats
    assert stats.rejected_invalid == 1 and stats.accepted == 1
    assert state.is_finite()
    np.testing.assert_array_equal(state.specific_force, held.specific_force)
    np.testing.assert_array_equal(state.angular_velocity, held.angular_velocity)
    np.testing.assert_array_equal(state.attitude, held.attitude)


def test_stale_watchdog_holds_the_last_state_and_marks_it(sender):
    packet = fgnetfdm_packet(24, A_X_pilot=2.0, A_Z_pilot=-30.0, phi=0.2)
    with FgNativeSource("fgnative:udp:127.0.0.1:0", rate_hz=100, stale_timeout_s=0.05) as src:
        it = iter(src)
        sender.sendto(packet, src.local_address)
        first = next(it)
        assert src.fresh
        states, fresh = [], []
        t0 = time.monotonic()
        while time.monotonic() - t0 < 0.3:  # nothing more is sent
            states.append(next(it))
            fresh.append(src.fresh)
        stats = src.stats
    assert not fresh[-1] and src.sample_age_s > 0.05
    assert stats.gaps == 1 and stats.stale_ticks >= 1
    for s in states:  # a hold of the last sample, never extrapolated
        np.testing.assert_array_equal(s.specific_force, first.specific_force)
        np.testing.assert_array_equal(s.attitude, first.attitude)
    ts = [s.t for s in [first, *states]]
    np.testing.assert_allclose(np.diff(ts), 0.01)  # ticks keep their rate while stale


def test_a_tick_stops_reading_when_its_drain_budget_is_spent(sender):
    """A flood cannot hold a tick back: once the tick is due and its drain budget spent, the
    source stops reading and the datagrams still queued wait for the next ticks (it read up to
    10,000 per pass first, 0.1-0.9 s). With a budget of 0 the first tick, due at once, reads
    the least a pass reads (MIN_READS) and holds the last of them; none of the rest is lost."""
    n = 2 * MIN_READS + 5
    packets = [fgnetfdm_packet(24, A_Z_pilot=-32.0, psi=0.01 * i) for i in range(n)]
    with FgNativeSource("fgnative:udp:127.0.0.1:0", rate_hz=100, drain_budget_s=0.0) as src:
        for p in packets:
            sender.sendto(p, src.local_address)
        it = iter(src)
        first = next(it)
        read_by_first_tick = src.stats.received
        while src.stats.received < n and src.stats.ticks < 100:
            next(it)
        stats = src.stats
    assert read_by_first_tick == MIN_READS
    assert first.attitude[2] == pytest.approx(0.01 * (MIN_READS - 1))
    assert stats.received == n and stats.accepted == n
    for bad in (-0.001, math.nan, math.inf, "1"):
        with pytest.raises(ConfigError, match="drain_budget_s"):
            FgNativeSource("fgnative:udp:127.0.0.1:0", drain_budget_s=bad)


@pytest.mark.parametrize(
    "url",
    [
        "fgnative:udp:127.0.0.1",
        "fgnative:tcp:127.0.0.1:5500",
        "fgnative:127.0.0.1:5500",
        "fgnative:udp:127.0.0.1:99999",
        "fgnative:udp::5500",
        "flightgear:udp:127.0.0.1:5500",
    ],
)
def test_bad_urls_give_one_line(url):
    with pytest.raises(ConfigError) as err:
        FgNativeSource(url)
    msg = str(err.value)
    assert "\n" not in msg and "fgnative:udp:" in msg


def test_port_in_use_is_a_source_error():
    with FgNativeSource("fgnative:udp:127.0.0.1:0") as a:
        port = a.local_address[1]
        with pytest.raises(SourceError, match="cannot listen"):
            FgNativeSource(f"fgnative:udp:127.0.0.1:{port}").open()


def test_describe_is_plain_data():
    src = FgNativeSource("fgnative:udp:0.0.0.0:5500", rate_hz=250)
    d = src.describe()
    assert d["kind"] == "fgnative" and d["listen"] == "0.0.0.0:5500" and d["rate_hz"] == 250
    assert d["versions"] == [24, 25]


def _stream_while_sending(sender, packet: bytes, out, duration_s: float) -> int:
    """``motionbase stream --source fgnative:...`` for ``duration_s`` s, logged to ``out``,
    while ``packet`` is sent to it every 10 ms; its exit status."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    stop = threading.Event()

    def send() -> None:
        while not stop.is_set():
            sender.sendto(packet, ("127.0.0.1", port))
            time.sleep(0.01)

    thread = threading.Thread(target=send, daemon=True)
    thread.start()
    try:
        url = f"fgnative:udp:127.0.0.1:{port}"
        return main(["stream", "--source", url, "--duration", str(duration_s), "--out", str(out)])
    finally:
        stop.set()
        thread.join()


def test_stream_command_takes_a_flightgear_url(tmp_path, capsys, sender):
    """``motionbase stream --source fgnative:...`` runs the pipeline on the packets, logs them."""
    packet = fgnetfdm_packet(24, A_X_pilot=1.5, A_Z_pilot=-31.0, phi=0.1, theta=0.05, psi=1.0)
    out = tmp_path / "fg.mcap"
    assert _stream_while_sending(sender, packet, out, 1.5) == 0
    states = [m for m in read_messages(out)["/aircraft/state"] if m["fresh"]]
    assert len(states) > 50
    f32 = lambda x: float(np.float32(x))  # noqa: E731
    for m in states:
        assert m["specific_force"] == [f32(1.5) * FT, 0.0, f32(-31.0) * FT]
        assert m["attitude"] == pytest.approx([0.1, 0.05, 1.0], abs=1e-7)
    assert McapSource(out).metadata["source"]["kind"] == "fgnative"
    assert "FlightGear:" in capsys.readouterr().out


MASS = 1000.0  # kg
LIFT = (0.0, 0.0, -MASS * G0)  # N on FlightGear's body axes (x forward, y right, z down)


@pytest.mark.parametrize(
    "force_n, body_rates, axis, sign",
    [
        ((3.0 * MASS, 0.0, -MASS * G0), (0, 0, 0), 0, 1),  # thrust: surge forward
        ((0.0, 3.0 * MASS, -MASS * G0), (0, 0, 0), 1, 1),  # a push to the right: sway right
        ((0.0, 0.0, -MASS * (G0 + 3.0)), (0, 0, 0), 2, -1),  # more lift: heave up (z up < 0)
        (LIFT, (0.3, 0, 0), 3, 1),  # rolling right (right wing down)
        (LIFT, (0, 0.3, 0), 4, 1),  # pitching up
        (LIFT, (0, 0, 0.3), 5, 1),  # yawing right
    ],
    ids=["surge", "sway", "heave", "roll", "pitch", "yaw"],
)
def test_stream_cues_each_push_and_rotation_its_own_way(
    tmp_path, sender, force_n, body_rates, axis, sign
):
    """Packets built from a force and a rotation on FlightGear's body axes (the pilot's
    acceleration is force over mass, what an accelerometer reads; the rates go out as Euler
    angle rates), streamed over loopback: the washout's cue moves the platform the same way
    (pose x forward, y right, z down; roll right, pitch up, yaw right positive)."""
    f_ft = [x / MASS / FT for x in force_n]
    rates = euler_rates(*body_rates, 0.0, 0.0)
    packet = fgnetfdm_packet(
        24,
        **dict(zip(("A_X_pilot", "A_Y_pilot", "A_Z_pilot"), f_ft, strict=True)),
        **dict(zip(("phidot", "thetadot", "psidot"), rates, strict=True)),
    )
    out = tmp_path / "cue.mcap"
    assert _stream_while_sending(sender, packet, out, 1.0) == 0
    poses = np.array([m["pose"] for m in read_messages(out)["/washout/pose"]])
    peak = poses[np.argmax(np.abs(poses[:, axis])), axis]
    assert sign * peak > 0.005  # m or rad


@pytest.mark.parametrize(
    "args, words",
    [
        (["--source", "fgnative:tcp:127.0.0.1:5500"], "only UDP"),
        (["--source", "udpin:127.0.0.1:14550"], "--mavlink"),
        (["--source", "xplane:127.0.0.1:49000", "--fast"], "--fast"),
        (["--source", "fgnative:udp:127.0.0.1:0", "--signing-key", "k.bin"], "--signing-key"),
        # it was ignored (exit 0): the command line's default, 1, hid it from the check
        (["--source", "fgnative:udp:127.0.0.1:5500", "--sysid", "7"], "--sysid"),
        (["--source", "xplane:127.0.0.1:49000", "--sysid", "1"], "--sysid"),
    ],
)
def test_stream_command_bad_source_is_one_line_and_exit_2(tmp_path, capsys, args, words):
    code = main(["stream", *args, "--duration", "1", "--out", str(tmp_path / "x.mcap")])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert "\n" not in err and words in err and "Traceback" not in err


def test_real_flightgear_packets(sender):
    """Datagrams recorded from fgfs 2020.3 (tests/data/README.md): parked on KSFO 28R."""
    raw = (DATA / "fgfs_2020.3_c172p_ksfo28r.fgnetfdm").read_bytes()
    packets = [raw[i : i + 408] for i in range(0, len(raw), 408)]
    assert len(packets) == 10
    with FgNativeSource("fgnative:udp:127.0.0.1:0", rate_hz=100) as src:
        it = iter(src)
        states = []
        for p in packets:
            sender.sendto(p, src.local_address)
            states.append(next(it))
            assert src.fresh and src.tick.new_sample
        stats = src.stats
    assert stats.accepted == 10 and stats.rejected == 0 and stats.extra["versions"] == "24"
    for s in states:
        roll, pitch, yaw = s.attitude
        # runway 28R's true heading is 297.9 deg; yaw comes wrapped to [-180, 180) deg
        assert math.degrees(yaw) == pytest.approx(297.9 - 360.0, abs=0.5)
        # at rest, an accelerometer reads minus gravity in body axes (FRD)
        g_body = G0 * np.array(
            [-math.sin(pitch), math.sin(roll) * math.cos(pitch), math.cos(roll) * math.cos(pitch)]
        )
        np.testing.assert_allclose(s.specific_force, -g_body, atol=0.1)
        np.testing.assert_allclose(s.angular_velocity, 0.0, atol=1e-3)


def test_a_second_sender_interleaved_is_refused_while_the_first_is_fresh(sender, caplog):
    """Two senders on the port (a second FlightGear, or anyone who can reach it) took turns
    in the held state: each tick jumped between two aircraft (here 0.3 and -0.3 rad of roll).
    The first sender is kept while it is fresh; the other's datagrams are counted, not used,
    and the source takes a new sender (a restarted FlightGear) once the first is stale."""
    other = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    mine = fgnetfdm_packet(24, A_Z_pilot=-32.0, phi=0.3)
    theirs = fgnetfdm_packet(24, A_Z_pilot=-32.0, phi=-0.3)
    try:
        with caplog.at_level(logging.WARNING, logger="motionbase"):
            with FgNativeSource(
                "fgnative:udp:127.0.0.1:0", rate_hz=100, stale_timeout_s=0.1
            ) as src:
                it = iter(src)
                rolls = []
                for _ in range(20):
                    sender.sendto(mine, src.local_address)
                    other.sendto(theirs, src.local_address)
                    time.sleep(0.002)
                    rolls.append(next(it).attitude[0])
                stats = src.stats
                t0 = time.monotonic()  # the first sender stops: the other one takes over
                while time.monotonic() - t0 < 30.0:  # (a watchdog, not a bound)
                    other.sendto(theirs, src.local_address)
                    last = next(it)
                    if src.fresh and last.attitude[0] < 0.0:
                        break
    finally:
        other.close()
    assert rolls[0] == pytest.approx(0.3) and all(r == rolls[0] for r in rolls)
    assert stats.accepted == 20 and stats.bad_data == 20 and stats.extra["other senders"] == 20
    assert src.fresh and last.attitude[0] == pytest.approx(-0.3)
    assert sum("another sender" in r.getMessage() for r in caplog.records) == 1
