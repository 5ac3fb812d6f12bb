"""Plots of platform workspaces (matplotlib, Agg canvas; no display needed).

The sweeps themselves are pure math in :mod:`motionbase.platform.rus6_workspace` (any 6-DOF
robot's ``reachable``); this module only draws them and writes the file, in the format its
extension names (``.png``, ``.svg``, ``.pdf``: :func:`plot_format`).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from motionbase.errors import ConfigError, SinkError
from motionbase.io.whole_files import folder_problem, whole_file
from motionbase.platform.rus6_workspace import AxisReach, WorkspaceSlices

__all__ = [
    "PLOT_FORMATS",
    "plot_format",
    "plot_rus6_workspace",
    "workspace_report",
    "save_figure",
]

#: The file formats a workspace plot is written in, by extension.
PLOT_FORMATS = ("png", "svg", "pdf")


def plot_format(path: str | Path) -> str:
    """The format a plot file's extension asks for (``png``, ``svg`` or ``pdf``).

    Raises
    ------
    ConfigError
        Another extension, or none: the file would not be what its name says.
    """
    suffix = Path(path).suffix.lower().lstrip(".")
    if suffix not in PLOT_FORMATS:
        what = f"extension .{suffix}" if suffix else "no extension"
        raise ConfigError(
            f"{path}: {what}: name the plot file .png, .svg or .pdf (its format follows it)"
        )
    return suffix


def save_figure(fig: Any, path: str | Path) -> Path:
    """Write a figure in the format its extension names, whole or not at all, into its
    folder (created, as ``fly --out`` creates its log's); a failing write is a SinkError."""
    p = Path(path)
    fmt = plot_format(p)
    problem = folder_problem(p.parent)
    if problem:
        raise SinkError(f"{p}: cannot write the plot: {problem}")
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        with whole_file(p) as part:  # a stop while it writes leaves no cut-off plot
            fig.savefig(part, format=fmt)
    except OSError as exc:
        raise SinkError(f"{p}: cannot write the plot: {exc.strerror or exc}") from None
    return p


def plot_rus6_workspace(
    slices: WorkspaceSlices,
    path: str | Path,
    *,
    envelope: list[AxisReach] | None = None,
    title: str = "6-RUS workspace",
) -> Path:
    """Draw the three reachability slices (z = 0, y = 0, x = 0) to a file.

    Parameters
    ----------
    slices : WorkspaceSlices
        From :func:`motionbase.platform.rus6_workspace.workspace_slices`.
    path : str or Path
        Output file: ``.png``, ``.svg`` or ``.pdf``.
    envelope : list of AxisReach, optional
        Single-axis reach, drawn as markers on the slices.
    title : str
        Figure title.

    Returns
    -------
    Path
        The file written.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.colors import ListedColormap
    from matplotlib.figure import Figure

    fig = Figure(figsize=(13, 4.6), dpi=110)
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 3)
    cmap = ListedColormap(["#f2f2f2", "#4c8bd6"])
    reach = {a.axis: a for a in envelope or []}
    # (grid, horizontal coords, vertical coords, labels, envelope axes (h, v), invert vertical)
    panels = [
        (
            slices.xy,
            slices.y,
            slices.x,
            "y (right), m",
            "x (forward), m",
            ("sway", "surge"),
            "top view, z = 0",
            False,
        ),
        (
            slices.xz,
            slices.x,
            slices.z,
            "x (forward), m",
            "z (down), m",
            ("surge", "heave"),
            "side view, y = 0",
            True,
        ),
        (
            slices.yz,
            slices.y,
            slices.z,
            "y (right), m",
            "z (down), m",
            ("sway", "heave"),
            "front view, x = 0",
            True,
        ),
    ]
    for ax, (grid, h, v, hl, vl, names, sub, inv) in zip(axes, panels, strict=True):
        # grids are indexed [first coordinate, second coordinate]; pcolormesh wants [v, h]
        img = grid if names == ("sway", "surge") else grid.T
        ax.pcolormesh(h, v, img.astype(float), cmap=cmap, vmin=0, vmax=1, shading="nearest")
        ax.set_xlabel(hl)
        ax.set_ylabel(vl)
        ax.set_title(sub)
        ax.set_aspect("equal")
        if inv:
            ax.invert_yaxis()
        hn, vn = names
        if hn in reach and vn in reach:
            ax.plot([-reach[hn].negative, reach[hn].positive], [0, 0], "k|-", lw=1)
            ax.plot([0, 0], [-reach[vn].negative, reach[vn].positive], "k_-", lw=1)
        ax.plot(0, 0, "k+", ms=10)
    roll, pitch, yaw = (math.degrees(a) for a in slices.orientation)
    fig.suptitle(
        f"{title}: reachable positions (blue) at roll {roll:.1f}, pitch {pitch:.1f}, "
        f"yaw {yaw:.1f} deg"
    )
    fig.tight_layout()
    return save_figure(fig, path)


def workspace_report(platform: str | Path | None = None, plot: str | Path | None = None) -> str:
    """The ``motionbase workspace`` job for a 6-DOF platform (any non-planar robot).

    Loads the robot and its geometry the way ``--platform`` names them
    (:func:`motionbase.platform.robot.load_geometry`: a robot's name, a preset name or a
    TOML path; default the 6-RUS :data:`~motionbase.config.DEFAULT_RUS6`), computes the
    single-axis envelope of its ``reachable`` and, if ``plot`` is given, draws the workspace
    slices at neutral orientation to that file (``.png``, ``.svg`` or ``.pdf``; another
    extension is refused before any work).

    Returns
    -------
    str
        The envelope table (and where the plot went), ready to print.
    """
    from motionbase.platform.robot import load_geometry, robot_spec
    from motionbase.platform.rus6_workspace import (
        format_envelope,
        single_axis_envelope,
        workspace_slices,
    )

    if plot is not None:
        plot_format(plot)
    name, geometry = load_geometry(None if platform is None else str(platform))
    spec = robot_spec(name)
    robot = spec.make(geometry)
    envelope = single_axis_envelope(robot)
    lim = robot.limits
    if robot.actuator_unit == "m":
        limits = f"actuator lengths {1000 * lim.lower.min():g} .. {1000 * lim.upper.max():g} mm"
    else:
        limits = (
            f"crank limits {math.degrees(lim.lower.min()):g} .. "
            f"{math.degrees(lim.upper.max()):g} deg"
        )
    kind = spec.description.split(" (")[0]
    text = [
        f"{kind} {geometry.name!r}: single-axis reach from neutral ({limits})",
        format_envelope(envelope),
    ]
    if plot is not None:
        slices = workspace_slices(robot)
        written = plot_rus6_workspace(
            slices, plot, envelope=envelope, title=f"{kind.split()[0]} {geometry.name}"
        )
        text.append(f"workspace slices written to {written}")
    return "\n".join(text)
