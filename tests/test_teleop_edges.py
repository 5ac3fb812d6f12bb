"""``motionbase teleop`` against what a user can get wrong or pull away during a run.

Found by an adversarial review of the teleop path (real CLI runs): each test here failed on
the code before its fix.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from motionbase import cli
from motionbase.io.mcap_source import read_messages

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
GEOMETRY = ROOT / "src" / "motionbase" / "presets" / "rrr3_udesc_symmetric.toml"


def _cursor_csv(path: Path) -> Path:
    path.write_text("t,x,y\n" + "".join(f"{k / 50},{600 + k},{350}\n" for k in range(20)))
    return path


def _cli(capfd, *args) -> tuple[int, str, str]:
    code = cli.main([str(a) for a in args])
    captured = capfd.readouterr()
    return code, captured.out, captured.err


@pytest.mark.parametrize("flag", ["--input", "--rrr3"])
def test_the_log_may_not_overwrite_a_file_the_run_reads(tmp_path, capfd, fresh_logger, flag):
    """``--out`` naming the cursor file or the geometry file: teleop read it, then wrote its
    MCAP log over it (the file was gone, the run said nothing). ``replay`` refuses its own
    recording as ``--out`` for the same reason."""
    csv = _cursor_csv(tmp_path / "cursor.csv")
    geometry = tmp_path / "robot.toml"
    shutil.copyfile(GEOMETRY, geometry)
    victim = csv if flag == "--input" else geometry
    before = victim.read_bytes()
    args = ["teleop", "--input", f"file:{csv}", "--rrr3", geometry, "--serial", "none"]
    code, _, err = _cli(capfd, *args, "--out", tmp_path / "." / victim.name)
    assert code == 2
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert "--out" in lines[0] and flag in lines[0] and "destroy" in lines[0]
    assert victim.read_bytes() == before


def test_a_log_removed_during_the_run_is_said_lost_with_exit_status_1(tmp_path):
    """The log's folder removed while teleop runs: the writer goes on into a file without a
    name. Teleop said nothing and exited 0; now it warns, as fly, replay and stream do, and
    exits 1 (the run was fine, its log was lost)."""
    folder = tmp_path / "logs"
    folder.mkdir()
    out = folder / "teleop.mcap"
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]  # (free again once closed, for the run to bind)
    proc = subprocess.Popen(
        [sys.executable, "-m", "motionbase", "teleop", "--input", f"udp:127.0.0.1:{port}",
         "--serial", "none", "--out", str(out)],
        env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        for _ in range(6000):  # the log exists once the run has opened everything
            if out.exists() or proc.poll() is not None:
                break
            time.sleep(0.01)
        assert proc.poll() is None, proc.communicate()
        shutil.rmtree(folder)
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 1, (stdout, stderr)
    assert "Traceback" not in stderr
    warnings = [ln for ln in stderr.splitlines() if ln.strip()]
    assert len(warnings) == 1 and str(out) in warnings[0] and "gone" in warnings[0], stderr
    assert "stopped by SIGINT" in stdout and "log lost" in stdout


@pytest.mark.parametrize("rate", ["5", "20000"])
def test_a_rate_the_loop_cannot_tick_at_names_the_option(tmp_path, capfd, fresh_logger, rate):
    """It named an internal ("command pipeline: rate_hz 5 is below 10 Hz")."""
    csv = _cursor_csv(tmp_path / "cursor.csv")
    code, _, err = _cli(capfd, "teleop", "--input", f"file:{csv}", "--rate", rate)
    assert code == 2
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert "--rate" in lines[0] and rate in lines[0]


def test_a_cursor_csv_saved_by_a_spreadsheet_is_read(tmp_path, capfd, fresh_logger):
    """ "CSV UTF-8" from a spreadsheet starts with a byte order mark: the header read as
    '\\ufefft' and the file was refused ("line 1: expected 't,x,y' numbers")."""
    csv = tmp_path / "cursor.csv"
    csv.write_bytes(b"\xef\xbb\xbft,x,y\r\n0,655,357\r\n0.2,700,357\r\n")
    out = tmp_path / "out.mcap"
    code, stdout, err = _cli(capfd, "teleop", "--input", f"file:{csv}", "--out", out)
    assert code == 0, err
    assert "stopped by end of input" in stdout
    pixels = [m["pixel"] for m in read_messages(out)["/cursor"]]
    assert pixels[0] == [655.0, 357.0] and pixels[-1] == [700.0, 357.0]


@pytest.mark.parametrize("rows", ["0,655,357\n", "t,x,y\n2,655,357\n2,700,300\n"])
def test_a_cursor_csv_that_lasts_no_time_is_one_line(tmp_path, capfd, fresh_logger, rows):
    """One row (or all at one time): the run ended on its first tick and said "stopped by
    end of input", exit 0, the robot a tick away from home and back: nothing told the
    user the file had no motion in it."""
    csv = tmp_path / "cursor.csv"
    csv.write_text(rows)
    code, stdout, err = _cli(capfd, "teleop", "--input", f"file:{csv}")
    assert code == 2 and not stdout, stdout
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and str(csv) in lines[0] and "no time" in lines[0], err


@pytest.mark.parametrize("host", ["in use", "10.1.2.3", "::1", "[::1]"])
def test_a_listen_address_that_cannot_be_bound_says_what_to_change(capfd, fresh_logger, host):
    """Every bind failure said "(choose another port)": for an address that is not this
    machine's (10.1.2.3) or not IPv4 (::1), another port does not help; [::1] was said not to
    resolve."""
    busy = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    busy.bind(("127.0.0.1", 0))
    port = busy.getsockname()[1]
    try:
        spec = f"udp:127.0.0.1:{port}" if host == "in use" else f"udp:{host}:{port}"
        code, _, err = _cli(capfd, "teleop", "--input", spec, "--duration", "0.1")
    finally:
        busy.close()
    assert code == 2
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    if host == "in use":
        assert "choose another port" in lines[0]
    else:
        assert "another port" not in lines[0] and "127.0.0.1" in lines[0], lines[0]


@pytest.mark.parametrize("value", ["-3", "nan", "x"])
def test_a_deadband_that_is_no_distance_or_without_udp_input_is_one_line(
    tmp_path, capfd, fresh_logger, value
):
    csv = _cursor_csv(tmp_path / "cursor.csv")
    for args in (["--input", "udp:127.0.0.1:9", "--deadband", value],
                 ["--input", f"file:{csv}", "--deadband", "10"]):  # fmt: skip
        try:
            code, _, err = _cli(capfd, "teleop", *args, "--duration", "0.1")
        except SystemExit as exc:  # (argparse's refusal of the option)
            code, err = exc.code, capfd.readouterr().err
        lines = [ln for ln in err.splitlines() if ln.strip()]
        assert code == 2 and "--deadband" in lines[-1] and "Traceback" not in err, err


def test_screen_names_the_size_the_cursor_pixels_are_on(tmp_path, capfd, fresh_logger):
    """A 1920 x 1080 screen without a calibration: the default map assumed the thesis's
    1310 x 715 window, so the right and lower parts of the screen were off the map. With
    ``--screen 1920x1080`` the screen's centre is the valid rectangle's centre and its
    corner the rectangle's corner."""
    from motionbase.platform import Rrr3, Rrr3Geometry

    csv = tmp_path / "cursor.csv"
    csv.write_text("0,960,540\n0.5,1920,1080\n1.0,1920,1080\n")
    out = tmp_path / "out.mcap"
    code, _, err = _cli(capfd, "teleop", "--input", f"file:{csv}", "--screen", "1920x1080",
                        "--rrr3", "udesc", "--out", out)  # fmt: skip
    assert code == 0, err
    x0, x1, y0, y1 = Rrr3(Rrr3Geometry.preset("udesc")).inscribed_rectangle(0.0)
    targets = [m["target"] for m in read_messages(out)["/cursor"]]
    assert targets[0] == pytest.approx([(x0 + x1) / 2, (y0 + y1) / 2], abs=1e-12)
    assert targets[-1] == pytest.approx([x1, y0], abs=1e-12)
    with pytest.raises(SystemExit):
        _cli(capfd, "teleop", "--input", f"file:{csv}", "--screen", "1920")
    err = capfd.readouterr().err
    assert "--screen" in err and "WIDTHxHEIGHT" in err and "Traceback" not in err


def test_a_deadband_of_zero_is_the_default_off(tmp_path, capfd, fresh_logger):
    """``--deadband 0`` is the default (off), as a script may say: it was refused as "not
    a positive number" (exit 2), a file input's run never started."""
    csv = _cursor_csv(tmp_path / "cursor.csv")
    code, _, err = _cli(capfd, "teleop", "--input", f"file:{csv}", "--serial", "none",
                        "--deadband", "0")  # fmt: skip
    assert code == 0 and "--deadband" not in err, err


def test_a_port_that_needs_privileges_says_to_choose_another_port(tmp_path):
    """udp:127.0.0.1:80 without the privilege to listen below 1024 (as root: with it taken
    away): "Permission denied" said to give another address, which does not help."""
    drop = ["setpriv", "--bounding-set", "-net_bind_service"] if os.geteuid() == 0 else []
    run = subprocess.run(
        [*drop, sys.executable, "-m", "motionbase.cli", "teleop", "--input", "udp:127.0.0.1:80",
         "--serial", "none", "--duration", "0.1"],
        cwd=tmp_path, env=ENV, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    lines = [ln for ln in run.stderr.splitlines() if ln.strip()]
    assert run.returncode == 2 and len(lines) == 1, run.stderr
    assert "Permission denied" in lines[0] and "port from 1024 up" in lines[0], lines[0]
    assert "address" not in lines[0].split("Permission denied")[1], lines[0]
