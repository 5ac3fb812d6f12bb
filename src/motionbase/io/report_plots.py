"""``motionbase report``: read a recording, draw the cueing plots (PNG), write the summary.

The numbers come from :func:`motionbase.report.build_report` (pure math); this
module reads the MCAP file, draws with matplotlib's Agg canvas (no display, no
global pyplot state) and writes ``DIR/*.png`` and ``DIR/summary.txt``.

Files written:

* ``specific_force.png``: aircraft specific force at the pilot against the platform's cue.
* ``angular_velocity.png``: aircraft body rates against the platform's.
* ``perceived.png``: otolith (m/s^2, deviation from 1 g) and semicircular-canal (deg/s)
  outputs, aircraft against platform.
* ``pose.png``: washout pose (before clamping) against the realised pose, on every tick;
  heave plotted up (the log's z is down).
* ``actuators.png``: crank angles (6-RUS), actuator lengths (6-UPS) or servo commands
  (planar) against their limits.
* ``timeline.png``: pipeline phase, clamping, rate limiting, held commands, fade.
* ``summary.txt``: the cueing metrics and run facts.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from motionbase.errors import ConfigError, SinkError
from motionbase.io.whole_files import folder_problem, whole_folder
from motionbase.report import AXES6, PHASES, Report, build_report

__all__ = [
    "ReportFiles",
    "default_report_dir",
    "plot_report",
    "read_recording",
    "report_figures",
    "write_report",
]

_AIR = "#1f4e9c"  # aircraft
_CUE = "#d9480f"  # platform
_REF = "#7a7a7a"  # references (washout, limits)
_PHASE_COLOURS = {
    "starting": "#ffe8a3",
    "running": "#d8f0d2",
    "stopping": "#ffd1b3",
    "parked": "#e0e0e0",
}


@dataclass(frozen=True)
class ReportFiles:
    """What :func:`write_report` produced.

    Attributes
    ----------
    report : Report
        The numbers.
    out_dir : Path
        The folder written.
    plots : tuple of Path
        The PNG files.
    summary : Path
        ``summary.txt``.
    """

    report: Report
    out_dir: Path
    plots: tuple[Path, ...]
    summary: Path

    def summary_text(self) -> str:
        """What the command prints: the summary and where the files went."""
        return (
            self.report.text.rstrip("\n")
            + f"\n\nreport: {len(self.plots)} plots and summary.txt in {self.out_dir}"
        )


def default_report_dir(recording: str | os.PathLike[str]) -> Path:
    """``<stem>_report/`` beside the recording."""
    p = Path(recording)
    return p.with_name(f"{p.stem}_report")


#: Topics the report does not use, left unread: the robot's drawing (``/platform/scene``,
#: about 75 kB a message decoded at 30 a second: 8 GB for an hour's stream) and ``/tf``.
UNREAD_TOPICS = ("/platform/scene", "/tf")


def read_recording(
    recording: str | os.PathLike[str],
) -> tuple[dict[str, list[dict[str, Any]]], dict[str, Any]]:
    """A recording's messages (but :data:`UNREAD_TOPICS`) and metadata, for
    :func:`~motionbase.report.build_report`.

    Raises
    ------
    SourceError, LogFormatError
        Missing or unreadable file, not MCAP, or no ``/aircraft/state`` messages.
    """
    from motionbase.io.mcap_source import read_messages, read_metadata

    src = Path(recording)
    # nothing to report: the error alone, without a warning that the file is cut short
    messages = read_messages(src, require="/aircraft/state", skip=UNREAD_TOPICS, json_only=False)
    return messages, read_metadata(src)


def write_report(
    recording: str | os.PathLike[str], out: str | os.PathLike[str] | None = None
) -> ReportFiles:
    """Read a recording and write its cueing report (PNGs and ``summary.txt``).

    Parameters
    ----------
    recording : path
        An MCAP file made by ``motionbase fly`` or ``replay``.
    out : path, optional
        Output folder (created); default ``<stem>_report/`` beside the recording.

    Raises
    ------
    ConfigError
        ``out`` is empty (an unset shell variable): the current folder is not taken for it.
    SourceError, LogFormatError
        Missing or unreadable file, not MCAP, or no ``/aircraft/state`` messages.
    SinkError
        The output folder cannot be written.
    """
    if out is not None and not str(out).strip():
        raise ConfigError(
            "--out: empty; give the folder for the report's files, or leave --out out "
            "for <stem>_report/ beside the recording"
        )
    src = Path(recording)
    messages, metadata = read_recording(src)
    report = build_report(messages, metadata, name=src.name)
    out_dir = Path(out) if out is not None else default_report_dir(src)
    problem = folder_problem(out_dir)
    if problem:
        raise SinkError(f"{out_dir}: cannot write the report: {problem}")
    try:  # all of the report or none of it (a stop while the plots are drawn)
        with whole_folder(out_dir) as staging:
            plots = [out_dir / p.name for p in plot_report(report, staging)]
            (staging / "summary.txt").write_text(report.text, encoding="utf-8")
    except OSError as exc:
        raise SinkError(f"{out_dir}: cannot write the report: {exc.strerror}") from None
    return ReportFiles(report, out_dir, tuple(plots), out_dir / "summary.txt")


# --------------------------------------------------------------------------- drawing


def _figure(rows: int, cols: int, height: float, width: float = 12.0):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, cols, sharex=True, squeeze=False)
    return fig, axes


def _save(fig: Any, path: Path) -> Path:
    try:
        fig.savefig(path)
    except OSError as exc:
        raise SinkError(f"{path}: cannot write: {exc.strerror}") from None
    return path


def _shade_phases(ax: Any, t: np.ndarray, phase: np.ndarray, dt: float) -> None:
    """Light background bands for the non-running phases."""
    if t.size == 0:
        return
    start = 0
    for i in range(1, t.size + 1):
        if i == t.size or phase[i] != phase[start]:
            name = str(phase[start])
            if name != "running":
                ax.axvspan(t[start], t[i - 1] + dt, color=_PHASE_COLOURS.get(name, "#eeeeee"), lw=0)
            start = i


def _title(report: Report, what: str) -> str:
    return f"{report.name} ({report.robot_title}): {what}"


def _specific_force_figure(r: Report) -> Any:
    fig, axes = _figure(3, 1, 8.5)
    labels = ("x (forward)", "y (right)", "z (down)")
    for i, ax in enumerate(axes[:, 0]):
        _shade_phases(ax, r.tick_t, r.phase, r.dt)
        ax.plot(r.t, r.aircraft_f[:, i], color=_AIR, lw=1.0, label="aircraft (at the pilot)")
        ax.plot(r.t, r.cue_f[:, i], color=_CUE, lw=1.0, label="platform cue (cab)")
        ax.set_ylabel(f"f {labels[i]} [m/s²]")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(loc="upper right", fontsize=8)
    axes[-1, 0].set_xlabel("time [s]")
    cue = "tilt + acceleration" if not r.planar else "planar motion mapped back (no tilt)"
    fig.suptitle(_title(r, f"specific force, aircraft vs platform cue ({cue}); shaded: start/stop"))
    return fig


def _angular_velocity_figure(r: Report) -> Any:
    fig, axes = _figure(3, 1, 8.5)
    labels = ("roll rate p", "pitch rate q", "yaw rate r")
    for i, ax in enumerate(axes[:, 0]):
        _shade_phases(ax, r.tick_t, r.phase, r.dt)
        ax.plot(r.t, np.degrees(r.aircraft_w[:, i]), color=_AIR, lw=1.0, label="aircraft")
        ax.plot(r.t, np.degrees(r.cue_w[:, i]), color=_CUE, lw=1.0, label="platform (cab)")
        ax.set_ylabel(f"{labels[i]} [deg/s]")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(loc="upper right", fontsize=8)
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle(_title(r, "body angular velocity, aircraft vs platform; shaded: start/stop"))
    return fig


def _perceived_figure(r: Report) -> Any:
    pm = r.perceived
    m = r.metrics
    fig, axes = _figure(3, 2, 8.5, 14.0)
    t = r.perceived_t
    f_labels = ("x", "y", "z")
    w_labels = ("roll", "pitch", "yaw")
    for i in range(3):
        ax = axes[i, 0]
        ax.plot(t, pm.aircraft_specific_force[:, i], color=_AIR, lw=1.0, label="aircraft")
        ax.plot(t, pm.platform_specific_force[:, i], color=_CUE, lw=1.0, label="platform")
        ax.set_ylabel(f"otolith {f_labels[i]} [m/s²]")
        ax.set_title(
            f"{f_labels[i]}: RMSE {m.rmse_specific_force[i]:.2f} m/s², "
            f"corr {_fmt(m.correlation_specific_force[i])}, "
            f"false cues {100 * m.false_cue_specific_force[i]:.1f} %",
            fontsize=9,
        )
        ax.grid(alpha=0.3)
        ax = axes[i, 1]
        ax.plot(t, np.degrees(pm.aircraft_angular_velocity[:, i]), color=_AIR, lw=1.0)
        ax.plot(t, np.degrees(pm.platform_angular_velocity[:, i]), color=_CUE, lw=1.0)
        ax.set_ylabel(f"canal {w_labels[i]} [deg/s]")
        ax.set_title(
            f"{w_labels[i]}: RMSE {np.degrees(m.rmse_angular_velocity[i]):.2f} deg/s, "
            f"corr {_fmt(m.correlation_angular_velocity[i])}, "
            f"false cues {100 * m.false_cue_angular_velocity[i]:.1f} %",
            fontsize=9,
        )
        ax.grid(alpha=0.3)
    axes[0, 0].legend(loc="upper right", fontsize=8)
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    fig.suptitle(
        _title(
            r,
            "perceived motion, running phase\notolith: sensed specific force minus level "
            "flight's 1 g, in m/s² (a steady force reads its true value); canals: sensed "
            "body rates",
        )
    )
    return fig


def _fmt(x: float) -> str:
    return "n/a" if not np.isfinite(x) else f"{x:.2f}"


#: Pose axes as plotted (in :data:`~motionbase.report.AXES6` order): which way is positive,
#: the factor from the logged value (m or rad, FRD) to the plotted one, and the unit. Heave is
#: plotted up: the log's z is down.
_POSE_AXES = (
    ("(forward)", 100.0, "cm"),
    ("(right)", 100.0, "cm"),
    ("up", -100.0, "cm"),
    ("(right down)", float(np.degrees(1.0)), "deg"),
    ("(nose up)", float(np.degrees(1.0)), "deg"),
    ("(nose right)", float(np.degrees(1.0)), "deg"),
)


def _pose_figure(r: Report) -> Any:
    fig, axes = _figure(3, 2, 8.5, 14.0)
    label = "realised (mapped back)" if r.planar else "realised (after clamp, safety)"
    for j, (name, (positive, k, unit)) in enumerate(zip(AXES6, _POSE_AXES, strict=True)):
        ax = axes[j % 3, j // 3]
        _shade_phases(ax, r.tick_t, r.phase, r.dt)
        ax.plot(
            r.tick_t, k * r.washout_pose[:, j], color=_REF, lw=1.0, ls="--", label="washout output"
        )
        ax.plot(r.tick_t, k * r.tick_cab_pose[:, j], color=_CUE, lw=1.0, label=label)
        lo, hi = r.reach[:, j]
        if np.isfinite(lo) and np.isfinite(hi):
            for v in (lo, hi):
                ax.axhline(k * v, color="#b00020", lw=0.8, ls=":")
        ax.set_ylabel(f"{name} {positive} [{unit}]")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(loc="upper right", fontsize=8)
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    note = " (cab units)" if r.planar else ""
    fig.suptitle(
        _title(r, f"platform pose{note}; dotted red: single-axis reach; shaded: start/stop")
    )
    return fig


def _actuators_figure(r: Report) -> Any:
    n = r.actuators.shape[1]
    rows = 3
    cols = (n + rows - 1) // rows
    fig, axes = _figure(rows, cols, 8.0, 12.0 if cols == 1 else 7.0 * cols)
    values, (lo, hi), unit = r.actuators_shown()
    for i in range(n):
        ax = axes[i % rows, i // rows]
        _shade_phases(ax, r.tick_t, r.phase, r.dt)
        ax.plot(r.tick_t, values[:, i], color=_CUE, lw=1.0, label=r.actuator_label)
        ax.axhline(lo[i], color="#b00020", lw=1.0, ls="--", label="limits")
        ax.axhline(hi[i], color="#b00020", lw=1.0, ls="--")
        span = hi[i] - lo[i]
        ax.set_ylim(lo[i] - 0.08 * span, hi[i] + 0.08 * span)
        ax.set_ylabel(f"{'motor' if r.planar else 'leg'} {i + 1} [{unit}]")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(loc="upper right", fontsize=8)
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    what = "servo commands (integer degrees)" if r.planar else f"{r.actuator_label}s"
    fig.suptitle(_title(r, f"{what} against their limits; shaded: start/stop"))
    return fig


def _timeline_figure(r: Report) -> Any:
    from matplotlib.patches import Patch

    fig, axes = _figure(2, 1, 4.8)
    ax = axes[0, 0]
    rows = [
        ("phase", None),
        ("clamped", r.clamped),
        ("rate-limited", r.rate_limited),
        ("held (unsafe)", r.held),
        ("input rejected", None),
    ]
    t, dt = r.tick_t, r.dt
    for k, (name, flags) in enumerate(rows):
        y = len(rows) - 1 - k
        if name == "phase":
            start = 0
            for i in range(1, t.size + 1):
                if i == t.size or r.phase[i] != r.phase[start]:
                    ph = str(r.phase[start])
                    ax.broken_barh(
                        [(t[start], t[i - 1] + dt - t[start])],
                        (y - 0.4, 0.8),
                        color=_PHASE_COLOURS.get(ph, "#eeeeee"),
                    )
                    start = i
            continue
        if name == "input rejected":
            tt, ff = r.t, r.rejected
        else:
            tt, ff = t, flags
        spans = _spans(tt, ff, dt)
        if spans:
            ax.broken_barh(spans, (y - 0.4, 0.8), color=_CUE)
        ax.text(
            1.003,
            y,
            f"{100 * np.mean(ff):.1f} %",
            transform=ax.get_yaxis_transform(),
            va="center",
            fontsize=8,
        )
    ax.set_yticks(range(len(rows)), [n for n, _ in reversed(rows)])
    ax.set_ylim(-0.6, len(rows) - 0.4)
    ax.grid(axis="x", alpha=0.3)
    ax.legend(
        handles=[Patch(color=_PHASE_COLOURS[p], label=p) for p in PHASES],
        loc="lower left",
        bbox_to_anchor=(0.0, 1.0),
        ncol=4,
        fontsize=8,
        frameon=False,
    )
    ax = axes[1, 0]
    ax.plot(t, r.fade, color=_CUE, lw=1.0)
    ax.set_ylim(-0.05, 1.1)
    ax.set_ylabel("watchdog fade [-]")
    ax.set_xlabel("time [s]")
    ax.grid(alpha=0.3)
    fig.suptitle(_title(r, "pipeline timeline (share of ticks on the right)"))
    return fig


def _spans(t: np.ndarray, flags: np.ndarray, dt: float) -> list[tuple[float, float]]:
    """Runs of True as ``(start, width)`` pairs for ``broken_barh``."""
    f = np.asarray(flags, dtype=bool)
    if not f.any():
        return []
    edges = np.diff(np.concatenate([[0], f.astype(np.int8), [0]]))
    starts = np.flatnonzero(edges == 1)
    ends = np.flatnonzero(edges == -1) - 1
    return [(float(t[a]), float(t[b] - t[a] + dt)) for a, b in zip(starts, ends, strict=True)]


def report_figures(report: Report) -> dict[str, Any]:
    """Every plot of a report as a matplotlib Figure (Agg canvas), by the file name it gets."""
    return {
        "specific_force.png": _specific_force_figure(report),
        "angular_velocity.png": _angular_velocity_figure(report),
        "perceived.png": _perceived_figure(report),
        "pose.png": _pose_figure(report),
        "actuators.png": _actuators_figure(report),
        "timeline.png": _timeline_figure(report),
    }


def plot_report(report: Report, out_dir: str | os.PathLike[str]) -> list[Path]:
    """Draw every plot of a report into ``out_dir`` (must exist); return the PNG paths."""
    d = Path(out_dir)
    return [_save(fig, d / name) for name, fig in report_figures(report).items()]
