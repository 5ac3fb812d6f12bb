"""``motionbase omct``: write the objective motion cueing test's files (JSON, tables, Bode plots).

The numbers come from :func:`motionbase.omct.run_omct` (pure math); this module draws with
matplotlib's Agg canvas (no display, no global pyplot state) and writes, in the output folder:

* ``omct.json``: every number (gain, phase, the linear response, clamped and rate-limited
  shares per frequency and test) with the settings and the pipeline configuration;
* ``table.md``: the compact table (measured gain and phase per frequency and test) that the
  README shows, with the command that produced it;
* ``table.txt``: the full table the command prints;
* ``bode_<test>.png``: one Bode plot per test (``pitch->surge`` is ``bode_pitch-surge.png``):
  the measured points, the classical washout's linear response as the chain realises it
  (line) and its continuous design (dotted); points where the clamp or an actuator limit
  acted are crossed.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from motionbase.errors import SinkError
from motionbase.io.whole_files import folder_problem, whole_folder

if TYPE_CHECKING:  # the result carries its numbers: no import of the pipeline here
    from motionbase.omct import OmctResult, TestResult

__all__ = ["OmctFiles", "bode_figure", "write_omct"]

_MEASURED = "#d9480f"
_LINEAR = "#1f4e9c"
_LIMIT = "#c92a2a"


@dataclass(frozen=True)
class OmctFiles:
    """What :func:`write_omct` produced.

    Attributes
    ----------
    result : OmctResult
    out_dir : Path
    files : tuple of Path
        Every file written.
    """

    result: OmctResult
    out_dir: Path
    files: tuple[Path, ...]

    def summary_text(self) -> str:
        """What the command prints: the full table and where the files went."""
        plots = sum(1 for f in self.files if f.suffix == ".png")
        return (
            self.result.table_text()
            + f"\n\nomct: {plots} Bode plots, omct.json, table.md and table.txt in {self.out_dir}"
        )


def _file_stem(name: str) -> str:
    return "bode_" + name.replace("->", "-")


def _plots_of_earlier_test(out_dir: Path) -> list[Path]:
    """The Bode plots an earlier test wrote into ``out_dir``: those of the tests its
    ``omct.json`` lists (none when there is no such file, or it is not one)."""
    try:
        tests = json.loads((out_dir / "omct.json").read_text(encoding="utf-8"))["tests"]
        names = [str(name) for name in tests]
    except (OSError, ValueError, KeyError, TypeError):
        return []
    return [out_dir / f"{_file_stem(n)}.png" for n in names if "/" not in n and "\\" not in n]


def write_omct(result: OmctResult, out: str | os.PathLike[str]) -> OmctFiles:
    """Write the test's JSON file, tables and Bode plots into the folder ``out`` (created),
    all of them or none (:func:`~motionbase.io.whole_files.whole_folder`: a stop while the
    plots are drawn leaves the folder as it was). The Bode plots of an earlier test there
    that this one did not run are removed (they would read as this test's); other files
    are kept.

    Raises
    ------
    SinkError
        The folder or a file cannot be written.
    """
    out_dir = Path(out)
    problem = folder_problem(out_dir)
    if problem:
        raise SinkError(f"{out_dir}: cannot write the test's files: {problem}")
    names = ["omct.json", "table.md", "table.txt"]
    names += [f"{_file_stem(r.test.name)}.png" for r in result.results]
    stale = [p for p in _plots_of_earlier_test(out_dir) if p.name not in names]
    try:
        with whole_folder(out_dir) as staging:
            (staging / "omct.json").write_text(
                json.dumps(result.to_dict(), indent=1) + "\n", encoding="utf-8"
            )
            (staging / "table.md").write_text(result.markdown(), encoding="utf-8")
            (staging / "table.txt").write_text(result.table_text() + "\n", encoding="utf-8")
            for r, name in zip(result.results, names[3:], strict=True):
                bode_figure(result, r).savefig(staging / name)
        for path in stale:  # (the new omct.json no longer lists them)
            path.unlink(missing_ok=True)
    except OSError as exc:
        raise SinkError(f"{out_dir}: cannot write the test's files: {exc.strerror}") from None
    return OmctFiles(result, out_dir, tuple(out_dir / name for name in names))


def _wrapped_line(z: np.ndarray) -> np.ndarray:
    """Phase in degrees in (-180, 180], with NaN where it wraps (no vertical line drawn)."""
    p = np.degrees(np.angle(z))
    jump = np.abs(np.diff(p)) > 180.0
    out = p.astype(float).copy()
    out[1:][jump] = np.nan
    return out


def _on_scale(gain: np.ndarray, log: bool) -> np.ndarray:
    """Gains as drawn: on a log axis, NaN where not positive (not drawn)."""
    return np.where(gain > 0, gain, np.nan) if log else np.asarray(gain, dtype=float)


def bode_figure(result: OmctResult, r: TestResult) -> Any:
    """The Bode plot of one test: gain (log-log) and phase, measured against linear.

    Returns
    -------
    matplotlib.figure.Figure
        On an Agg canvas (no display).
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.5, 6.5), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    ax_g, ax_p = fig.subplots(2, 1, sharex=True)
    w = r.frequencies
    phase = r.phase_deg  # in (-180, 180], as in the tables
    curves = result.linear_curves(r)
    # a channel switched off (gain 0) has nothing to draw on a log scale: the gain axis is
    # then linear, so the zeros show (and matplotlib does not warn on the terminal)
    shown = [r.gain] + ([np.abs(curves[1]), np.abs(curves[2])] if curves is not None else [])
    log_gain = any((g > 0).any() for g in shown)
    ax_g.set_xscale("log")
    if log_gain:
        ax_g.set_yscale("log")
    if curves is not None:
        dense, lin, design = curves
        lin_phase = _wrapped_line(lin)
        design_phase = _wrapped_line(design)
        lin_g, design_g = (_on_scale(np.abs(z), log_gain) for z in (lin, design))
        ax_g.plot(dense, lin_g, color=_LINEAR, lw=1.5, label="classical washout, linear")
        ax_g.plot(dense, design_g, color=_LINEAR, lw=1.0, ls=":", label="continuous design")
        ax_p.semilogx(dense, lin_phase, color=_LINEAR, lw=1.5)
        ax_p.semilogx(dense, design_phase, color=_LINEAR, lw=1.0, ls=":")
    gain = _on_scale(r.gain, log_gain)
    ax_g.plot(w, gain, "o", color=_MEASURED, ms=6, label="measured (whole chain)")
    ax_p.semilogx(w, phase, "o", color=_MEASURED, ms=6)
    hit = (r.clamped > 0) | (r.limited > 0)
    if hit.any():
        label = "clamp or actuator limit acted"
        ax_g.plot(w[hit], gain[hit], "x", color=_LIMIT, ms=10, mew=2, label=label)
        ax_p.semilogx(w[hit], phase[hit], "x", color=_LIMIT, ms=10, mew=2)
    unit = "" if r.test.gain_unit == "-" else f" [{r.test.gain_unit}]"
    ax_g.set_ylabel(f"gain{unit}")
    ax_p.set_ylabel("phase [deg]")
    ax_p.set_ylim(-185.0, 185.0)
    ax_p.set_yticks(np.arange(-180.0, 181.0, 45.0))
    ax_p.set_xlabel("frequency [rad/s]")
    for ax in (ax_g, ax_p):
        ax.grid(True, which="both", alpha=0.3)
    ax_g.legend(loc="best", fontsize="small")
    ax_g.set_title(f"OMCT {r.test.name}: {r.test.title}\n{result.robot_label}", fontsize="medium")
    return fig
