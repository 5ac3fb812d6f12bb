"""X-Plane source against a stand-in X-Plane on loopback UDP.

The stand-in answers RREF subscriptions as "Exchanging Data with X-Plane.rtfd"
describes them (request ``"RREF\\0"`` + int32 freq + int32 index + 400-byte path;
answers ``"RREF,"`` + (int32 index, float32 value) pairs, little endian, at the
requested rate; freq 0 ends a subscription), forgets them when it restarts, and
the legacy DATA output is sent as ``"DATA*"`` + 36-byte records (int32 group + 8
float32). Everything is packed here from those documents, not with the module.
"""

from __future__ import annotations

import logging
import math
import socket
import struct
import threading
import time

import numpy as np
import pytest

from motionbase.cli import main
from motionbase.errors import ConfigError
from motionbase.io.mcap_source import read_messages
from motionbase.io.xplane_source import XPlaneSource

G0 = 9.80665
RAD = math.pi / 180


def f32(x: float) -> float:
    return float(np.float32(x))


# a banked turn, in X-Plane's units and signs (DataRefs.txt)
TURN = {
    "sim/flightmodel/forces/g_axil": -0.1,  # accelerating forward (forward load negative)
    "sim/flightmodel/forces/g_side": 0.05,
    "sim/flightmodel/forces/g_nrml": 1.15,
    "sim/flightmodel/position/P": 2.0,  # deg/s
    "sim/flightmodel/position/Q": 3.0,
    "sim/flightmodel/position/R": -4.0,
    "sim/flightmodel/position/phi": 30.0,  # deg
    "sim/flightmodel/position/theta": 5.0,
    "sim/flightmodel/position/psi": 270.0,  # true heading
    "sim/version/xplane_internal_version": 120100,
}
LEVEL = {
    **{k: 0.0 for k in TURN},
    "sim/flightmodel/forces/g_nrml": 1.0,
    "sim/flightmodel/position/psi": 90.0,
    "sim/version/xplane_internal_version": 120100,
}


# X-Plane's aircraft axes (DataRefs.txt: ACF X right, "fside_plug_acf ... positive pushes airplane
# to the right"; ACF Y up; ACF Z aft, "faxil_plug_acf ... positive pushes airplane backward").
# g_side, g_nrml, g_axil are the total force on ACF X, Y, Z over the weight (Laminar's
# MotionPlatformData sample sums the same fside/fnrml/faxil forces over the mass). Body FRD:
# forward = -Z, right = +X, down = -Y.
FRD_FROM_ACF = np.array([[0, 0, -1], [1, 0, 0], [0, -1, 0]])


def g_loads(force_acf_n, mass_kg: float) -> dict[str, float]:
    """X-Plane's g-load datarefs for a total non-gravitational force (ACF X, Y, Z, N)."""
    fx, fy, fz = np.asarray(force_acf_n, float) / (mass_kg * G0)
    return {
        "sim/flightmodel/forces/g_axil": fz,
        "sim/flightmodel/forces/g_side": fx,
        "sim/flightmodel/forces/g_nrml": fy,
    }


def expected(values: dict[str, float]):
    """The state the source must give, from the documented units and axes."""
    g = [f32(values[f"sim/flightmodel/forces/{n}"]) for n in ("g_side", "g_nrml", "g_axil")]
    f = FRD_FROM_ACF @ (G0 * np.array(g))  # specific force: force over mass, in FRD
    w = [f32(values[f"sim/flightmodel/position/{n}"]) * RAD for n in "PQR"]
    att = [f32(values[f"sim/flightmodel/position/{n}"]) * RAD for n in ("phi", "theta", "psi")]
    att[2] = (att[2] + math.pi) % (2 * math.pi) - math.pi
    return np.array(f), np.array(w), np.array(att)


class FakeXPlane:
    """Answers RREF subscriptions like X-Plane; can also send DATA packets."""

    def __init__(self, values: dict[str, float], port: int = 0, answer_rref: bool = True):
        self.values = dict(values)
        self.answer_rref = answer_rref
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", port))
        self.sock.settimeout(0.002)
        self.port = self.sock.getsockname()[1]
        self.requests: list[tuple[int, int, str, int]] = []  # freq, index, path, size
        self.subs: dict[tuple, list] = {}  # (client, index) -> [freq, path, next_due]
        self.sent = 0
        self._run = True
        self._lock = threading.Lock()
        self.thread = threading.Thread(target=self._loop, daemon=True)
        self.thread.start()

    def _loop(self) -> None:
        while self._run:
            try:
                data, addr = self.sock.recvfrom(2048)
            except TimeoutError:
                data = None
            except OSError:
                return
            if data is not None and data[:5] == b"RREF\0" and len(data) == 413:
                freq, index = struct.unpack_from("<ii", data, 5)
                path = data[13:].split(b"\0", 1)[0].decode()
                with self._lock:
                    self.requests.append((freq, index, path, len(data)))
                    if freq == 0:
                        self.subs.pop((addr, index), None)
                    else:
                        self.subs[(addr, index)] = [freq, path, time.monotonic()]
            if self.answer_rref:
                self._answer()

    def _answer(self) -> None:
        now = time.monotonic()
        out: dict[tuple, bytearray] = {}
        with self._lock:
            for (addr, index), sub in self.subs.items():
                freq, path, due = sub
                if now >= due and path in self.values:
                    sub[2] = max(due + 1.0 / freq, now - 0.1)
                    pkt = out.setdefault(addr, bytearray(b"RREF,"))
                    pkt += struct.pack("<if", index, self.values[path])
        for addr, pkt in out.items():
            try:
                self.sock.sendto(bytes(pkt), addr)
                self.sent += 1
            except OSError:
                pass

    def send_data(self, addr, records: list[tuple[int, list[float]]]) -> None:
        pkt = b"DATA*" + b"".join(struct.pack("<i8f", g, *(v + [0.0] * 8)[:8]) for g, v in records)
        self.sock.sendto(pkt, addr)

    def unsubscribed(self) -> set[str]:
        with self._lock:
            return {path for freq, _, path, _ in self.requests if freq == 0}

    def subscribed(self) -> dict[str, int]:
        with self._lock:
            return {path: freq for freq, _, path, _ in self.requests if freq > 0}

    def stop(self) -> None:
        self._run = False
        self.thread.join(timeout=2)
        self.sock.close()


@pytest.fixture
def xplane():
    fakes: list[FakeXPlane] = []

    def start(values=TURN, port=0, answer_rref=True) -> FakeXPlane:
        fake = FakeXPlane(values, port, answer_rref)
        fakes.append(fake)
        return fake

    yield start
    for f in fakes:
        if f._run:
            f.stop()


def _until(src, it, cond, timeout_s=30.0):  # (a watchdog, not a bound)
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        state = next(it)
        if cond(state):
            return state
    raise AssertionError(f"condition not met in {timeout_s} s (stats {src.stats})")


def test_rref_subscribes_converts_and_unsubscribes(xplane):
    xp = xplane(TURN)
    url = f"xplane:127.0.0.1:{xp.port}?listen=127.0.0.1:0"
    with XPlaneSource(url, rate_hz=100) as src:
        it = iter(src)
        # the motion datarefs come at 100 Hz, the version at 1 Hz: either may come first
        state = _until(src, it, lambda s: src.fresh and src.stats.extra.get("X-Plane version"))
        f, w, att = expected(TURN)
        np.testing.assert_allclose(state.specific_force, f, atol=1e-9)
        np.testing.assert_allclose(state.angular_velocity, w, atol=1e-9)
        np.testing.assert_allclose(state.attitude, att, atol=1e-9)
        assert state.specific_force[0] > 0  # speeding up: the seat pushes forward
        stats = src.stats
        assert stats.extra["X-Plane version"] == 12
    subs = xp.subscribed()
    assert {k: v for k, v in subs.items() if "version" not in k} == {
        k: 100 for k in TURN if "version" not in k
    }
    assert subs["sim/version/xplane_internal_version"] == 1
    assert all(size == 413 for *_, size in xp.requests)
    t0 = time.monotonic()  # the stand-in reads the freq-0 requests in its own thread
    while xp.unsubscribed() != set(TURN) and time.monotonic() - t0 < 30.0:
        time.sleep(0.01)
    assert xp.unsubscribed() == set(TURN)
    with xp._lock:
        assert xp.subs == {}  # X-Plane has nothing left to send
    assert stats.rejected == 0


def test_level_flight_reads_minus_g():
    """g_nrml = 1 in level flight is f = (0, 0, -g) (DESIGN.md's convention)."""
    f, w, att = expected(LEVEL)
    np.testing.assert_allclose(f, [0, 0, -G0])


MASS = 1000.0  # kg
# on the runway, the gear carries the weight (ACF Y up: +m g0); ACF Z is aft, X right
TAKEOFF_ROLL = g_loads([0.0, MASS * G0, -2500.0], MASS)  # net thrust 2500 N forward
RIGHT_PUSH = g_loads([981.0, MASS * G0, 0.0], MASS)  # 981 N pushing the airplane right


@pytest.mark.parametrize("stream", ["rref", "data"])
@pytest.mark.parametrize(
    ("loads", "f_frd"),
    [(TAKEOFF_ROLL, [2.5, 0.0, -G0]), (RIGHT_PUSH, [0.0, 0.981, -G0])],
    ids=["takeoff_roll", "right_push"],
)
def test_specific_force_follows_the_force_on_the_airplane(xplane, stream, loads, f_frd):
    """A force pushing the airplane forward (right) is a specific force forward (right) in FRD:
    the seat pushes the pilot that way. X-Plane sends the loads as datarefs (RREF) or in DATA
    group 4 (values 4, 5, 6 = normal, axial, side)."""
    values = {**LEVEL, **loads}
    xp = xplane(values, answer_rref=stream == "rref")
    url = f"xplane:127.0.0.1:{xp.port}?listen=127.0.0.1:0&version=12"
    with XPlaneSource(url, rate_hz=100) as src:
        it = iter(src)
        if stream == "rref":
            state = _until(src, it, lambda s: src.fresh)
        else:
            next(it)
            g = [loads[f"sim/flightmodel/forces/{n}"] for n in ("g_nrml", "g_axil", "g_side")]
            xp.send_data(src.local_address, [(4, [0.1, 0.0, 0.0, 0.0, *g])])
            state = next(it)
    np.testing.assert_allclose(state.specific_force, f_frd, atol=1e-5)


def test_resubscribes_when_xplane_restarts(xplane, caplog):
    xp = xplane(TURN)
    port = xp.port
    url = f"xplane:127.0.0.1:{port}?listen=127.0.0.1:0"
    with caplog.at_level(logging.INFO, logger="motionbase"):
        with XPlaneSource(url, rate_hz=100, stale_timeout_s=0.2) as src:
            it = iter(src)
            _until(src, it, lambda s: src.fresh)
            n_sub = src.stats.extra["subscriptions sent"]
            xp.stop()  # X-Plane quits: its subscriptions are gone
            _until(src, it, lambda s: not src.fresh)
            time.sleep(0.3)
            banked = dict(TURN, **{"sim/flightmodel/position/phi": -20.0})
            xp2 = xplane(banked, port=port)  # X-Plane is back, knowing nothing of us
            state = _until(src, it, lambda s: src.fresh)
            stats = src.stats
    assert xp2.subscribed(), "the source did not subscribe again"
    assert stats.extra["subscriptions sent"] > n_sub
    assert stats.gaps == 1
    np.testing.assert_allclose(state.attitude[0], -20.0 * RAD, atol=1e-7)
    messages = [r.getMessage() for r in caplog.records]
    assert any("subscribing again" in m for m in messages)
    assert any("RREF answers again" in m for m in messages)


def _data_records(p_deg, q_deg, r_deg, xp11=False):
    """DATA groups 4, 16, 17 for TURN (group 16 as X-Plane 11 or 12 lays it out)."""
    g4 = [0.2, 0.0, 100.0, 0.0, 1.15, -0.1, 0.05, 0.0]  # Mach, -, VVI, -, normal, axial, side
    if xp11:
        g16 = [q_deg * RAD, p_deg * RAD, r_deg * RAD]  # Q, P, R in rad/s
    else:
        g16 = [p_deg, q_deg, r_deg]  # P, Q, R in deg/s
    g17 = [5.0, 30.0, 270.0, 268.0]  # pitch, roll, true heading, magnetic heading
    return [(4, g4), (16, g16), (17, g17), (3, [100.0, 101.0, 102.0])]


@pytest.mark.parametrize("version", [11, 12])
def test_legacy_data_output(xplane, version):
    xp = xplane(TURN, answer_rref=False)  # X-Plane that does not accept incoming UDP
    url = f"xplane:127.0.0.1:{xp.port}?listen=127.0.0.1:0&version={version}"
    with XPlaneSource(url, rate_hz=100) as src:
        it = iter(src)
        next(it)
        xp.send_data(src.local_address, _data_records(2.0, 3.0, -4.0, xp11=version == 11))
        state = next(it)
        assert src.fresh
        stats = src.stats
    f, w, att = expected(TURN)
    np.testing.assert_allclose(state.specific_force, f, atol=1e-6)
    np.testing.assert_allclose(state.angular_velocity, w, atol=1e-6)
    np.testing.assert_allclose(state.attitude, att, atol=1e-6)
    assert stats.extra["DATA datagrams"] == 1 and stats.rejected == 0


def test_data_group_16_waits_for_the_version(xplane, caplog):
    xp = xplane(TURN, answer_rref=False)
    url = f"xplane:127.0.0.1:{xp.port}?listen=127.0.0.1:0"
    with caplog.at_level(logging.WARNING, logger="motionbase"):
        with XPlaneSource(url, rate_hz=100) as src:
            it = iter(src)
            next(it)
            for _ in range(3):
                xp.send_data(src.local_address, _data_records(2.0, 3.0, -4.0))
            state = next(it)
            assert not src.fresh  # body rates unknown: not a complete, fresh state
    np.testing.assert_allclose(state.angular_velocity, 0.0)
    f, _, att = expected(TURN)
    np.testing.assert_allclose(state.specific_force, f, atol=1e-6)
    np.testing.assert_allclose(state.attitude, att, atol=1e-6)
    warnings = [r for r in caplog.records if "group 16" in r.getMessage()]
    assert len(warnings) == 1


def test_data_version_learned_from_xplane(xplane):
    """X-Plane answers only the version dataref; group 16 is then read as X-Plane 12's."""
    xp = xplane({"sim/version/xplane_internal_version": 120100})
    url = f"xplane:127.0.0.1:{xp.port}?listen=127.0.0.1:0"
    with XPlaneSource(url, rate_hz=100) as src:
        it = iter(src)
        _until(src, it, lambda s: src.stats.extra.get("X-Plane version") == 12)
        xp.send_data(src.local_address, _data_records(2.0, 3.0, -4.0))
        state = next(it)
        assert src.fresh
    np.testing.assert_allclose(state.angular_velocity, np.array([2.0, 3.0, -4.0]) * RAD, atol=1e-7)


def test_rref_wins_over_data_while_fresh(xplane):
    xp = xplane(TURN)
    url = f"xplane:127.0.0.1:{xp.port}?listen=127.0.0.1:0"
    with XPlaneSource(url, rate_hz=100) as src:
        it = iter(src)
        _until(src, it, lambda s: src.fresh)
        records = _data_records(20.0, 30.0, -40.0)
        records[2] = (17, [-5.0, -30.0, 90.0, 0.0])  # a different attitude
        xp.send_data(src.local_address, records)
        state = next(it)
    _, w, att = expected(TURN)
    np.testing.assert_allclose(state.attitude, att, atol=1e-7)
    np.testing.assert_allclose(state.angular_velocity, w, atol=1e-7)


def test_invalid_values_are_rejected_one_by_one(xplane):
    xp = xplane(TURN)
    url = f"xplane:127.0.0.1:{xp.port}?listen=127.0.0.1:0"
    with XPlaneSource(url, rate_hz=100) as src:
        it = iter(src)
        held = _until(src, it, lambda s: src.fresh)
        xp.answer_rref = False
        time.sleep(0.02)
        before = src.stats.rejected_invalid
        # one datagram: NaN g_nrml, absurd P, roll 200 deg, and a valid new pitch
        pkt = b"RREF," + b"".join(
            struct.pack("<if", 1700 + i, v)
            for i, v in ((2, float("nan")), (3, 1e5), (6, 200.0), (7, 10.0))
        )
        xp.sock.sendto(pkt, src.local_address)
        state = next(it)
        stats = src.stats
    assert stats.rejected_invalid - before == 3
    assert state.is_finite()
    assert state.specific_force[2] == held.specific_force[2]
    assert state.angular_velocity[0] == held.angular_velocity[0]
    assert state.attitude[0] == held.attitude[0]
    assert state.attitude[1] == pytest.approx(10.0 * RAD)


def test_datagrams_from_another_host_are_refused(xplane):
    xp = xplane(TURN, answer_rref=False)
    url = f"xplane:127.0.0.1:{xp.port}?listen=127.0.0.1:0"
    other = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    other.bind(("127.0.0.2", 0))  # another loopback address: not X-Plane's host
    try:
        with XPlaneSource(url, rate_hz=100) as src:
            it = iter(src)
            next(it)
            other.sendto(b"RREF," + struct.pack("<if", 1708, 45.0), src.local_address)
            state = next(it)
            stats = src.stats
    finally:
        other.close()
    assert stats.extra["from other hosts"] == 1 and stats.accepted == 0
    assert state.attitude[2] == 0.0


def test_the_silence_warning_names_the_host_whose_datagrams_were_refused(xplane, caplog):
    """X-Plane's Data Output reaching motionbase from another address than the one given (a
    second network card, X-Plane on this PC sending from its LAN address) is refused; the
    warning named only the silence of the given host and told the user to set up the Data
    Output they had set up. It names the refused sender and the URL that takes it."""
    xp = xplane(TURN, answer_rref=False)
    url = f"xplane:127.0.0.1:{xp.port}?listen=127.0.0.1:0&version=12"
    other = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    other.bind(("127.0.0.2", 0))  # X-Plane's Data Output, sending from another address
    records = b"DATA*" + b"".join(
        struct.pack("<i8f", g, *(v + [0.0] * 8)[:8]) for g, v in _data_records(2.0, 3.0, -4.0)
    )

    def told(_state) -> bool:
        other.sendto(records, src.local_address)
        return any("127.0.0.2" in r.getMessage() for r in caplog.records)

    try:
        with caplog.at_level(logging.WARNING, logger="motionbase"):
            with XPlaneSource(url, rate_hz=100) as src:
                _until(src, iter(src), told)
    finally:
        other.close()
    (line,) = [r.getMessage() for r in caplog.records if "127.0.0.2" in r.getMessage()]
    assert f"xplane:127.0.0.2:{xp.port}" in line


def test_the_silence_warning_never_names_a_wildcard_as_a_destination():
    """Listening on every address (X-Plane on another PC), the silence warning told the user
    to set X-Plane's Data Output to send to 0.0.0.0:49005, which is no address to send to."""
    src = XPlaneSource("xplane:192.168.1.20:49000")  # (not opened: nothing is bound)
    hint = src._silence_hint(3.0)
    assert "0.0.0.0" not in hint and "this PC's IP address" in hint and "49005" in hint


@pytest.mark.parametrize(
    "url",
    [
        "xplane:127.0.0.1",
        "xplane:127.0.0.1:0",
        "xplane:127.0.0.1:49000?version=10",
        "xplane:127.0.0.1:49000?listen=abc",
        "xplane:127.0.0.1:49000?colour=red",
        "xplane:127.0.0.1:49000?listen=70000",
        "xplane:notahost.invalid:49000",
        "x-plane:127.0.0.1:49000",
    ],
)
def test_bad_urls_give_one_line(url):
    with pytest.raises(ConfigError) as err:
        XPlaneSource(url)
    assert "\n" not in str(err.value) and "xplane" in str(err.value)


@pytest.mark.parametrize(
    "url",
    [
        "xplane:127.0.0.1:49005",  # 49005: where motionbase listens (and Data Output sends)
        "xplane:localhost:49010?listen=49010",
        "xplane:127.0.0.1:49010?listen=0.0.0.0:49010",
    ],
)
def test_xplane_s_port_that_is_the_listening_port_is_refused(url, capsys):
    """X-Plane given at the address motionbase listens on: the source subscribed to itself,
    read its own requests as RREF answers and ran with every tick stale, the warning naming
    X-Plane's silence. It is one line, exit 2, naming the mix-up."""
    with pytest.raises(ConfigError, match="the port motionbase listens on"):
        XPlaneSource(url)
    assert main(["stream", "--source", url, "--duration", "1"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "49000" in err


def test_default_listen_address_follows_xplane_host():
    assert XPlaneSource("xplane:127.0.0.1:49000").describe()["listen"] == "127.0.0.1:49005"
    remote = XPlaneSource("xplane:192.168.1.20:49000?listen=49010")
    assert remote.describe()["listen"] == "0.0.0.0:49010"
    assert remote.describe()["rref_freq_hz"] == 100


def test_stream_command_takes_an_xplane_url(xplane, tmp_path, capsys):
    xp = xplane(TURN)
    out = tmp_path / "xp.mcap"
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:  # the command refuses port 0
        s.bind(("127.0.0.1", 0))
        listen = s.getsockname()[1]
    url = f"xplane:127.0.0.1:{xp.port}?listen=127.0.0.1:{listen}"
    code = main(["stream", "--source", url, "--duration", "1.5", "--out", str(out)])
    assert code == 0
    states = [m for m in read_messages(out)["/aircraft/state"] if m["fresh"]]
    assert len(states) > 50
    f, w, att = expected(TURN)
    for m in states:
        np.testing.assert_allclose(m["specific_force"], f, atol=1e-9)
        np.testing.assert_allclose(m["angular_velocity"], w, atol=1e-9)
        np.testing.assert_allclose(m["attitude"], att, atol=1e-9)
    assert "X-Plane:" in capsys.readouterr().out
    t0 = time.monotonic()
    while xp.unsubscribed() != set(TURN) and time.monotonic() - t0 < 30.0:
        time.sleep(0.01)
    assert xp.unsubscribed() == set(TURN)  # the command unsubscribed on its way out


def test_a_listen_port_of_0_is_for_programs_only():
    """Port 0 listens on a free port that a program reads back from ``local_address``; the
    command line passes ``free_port=False``: nobody could send to a port it does not show."""
    url = "xplane:127.0.0.1:49000?listen=0"
    assert XPlaneSource(url).listen_port == 0
    with pytest.raises(ConfigError, match=r"port 0 is out of range \(1\.\.65535\)"):
        XPlaneSource(url, free_port=False)
