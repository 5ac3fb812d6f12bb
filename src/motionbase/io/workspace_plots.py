"""PNG plots of platform workspaces (matplotlib, Agg canvas; no display needed).

The sweeps themselves are pure math in :mod:`motionbase.platform.rus6_workspace`; this module
only draws them and writes the file.
"""

from __future__ import annotations

import math
from pathlib import Path

from motionbase.errors import SinkError
from motionbase.platform.rus6_workspace import AxisReach, WorkspaceSlices

__all__ = ["plot_rus6_workspace"]


def plot_rus6_workspace(
    slices: WorkspaceSlices,
    path: str | Path,
    *,
    envelope: list[AxisReach] | None = None,
    title: str = "6-RUS workspace",
) -> Path:
    """Draw the three reachability slices (z = 0, y = 0, x = 0) to a PNG file.

    Parameters
    ----------
    slices : WorkspaceSlices
        From :func:`motionbase.platform.rus6_workspace.workspace_slices`.
    path : str or Path
        Output PNG file.
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
    p = Path(path)
    try:
        fig.savefig(p, format="png")
    except OSError as exc:
        raise SinkError(f"{p}: cannot write the plot: {exc.strerror or exc}") from None
    return p


def rus6_workspace_report(platform: str | Path = "ceart", plot: str | Path | None = None) -> str:
    """The ``motionbase workspace`` job for a 6-RUS platform.

    Loads the geometry (preset name or TOML path), computes the single-axis envelope and,
    if ``plot`` is given, draws the workspace slices at neutral orientation to that PNG.

    Returns
    -------
    str
        The envelope table (and where the plot went), ready to print.
    """
    from motionbase.platform.rus6 import Rus6
    from motionbase.platform.rus6_geometry import Rus6Geometry
    from motionbase.platform.rus6_workspace import (
        format_envelope,
        single_axis_envelope,
        workspace_slices,
    )

    geometry = Rus6Geometry.preset(str(platform))
    rus6 = Rus6(geometry)
    envelope = single_axis_envelope(rus6)
    lo, hi = rus6.angle_limits
    text = [
        f"6-RUS platform {geometry.name!r}: single-axis reach from neutral "
        f"(crank limits {math.degrees(lo.min()):g} .. {math.degrees(hi.max()):g} deg)",
        format_envelope(envelope),
    ]
    if plot is not None:
        slices = workspace_slices(rus6)
        written = plot_rus6_workspace(
            slices, plot, envelope=envelope, title=f"6-RUS {geometry.name}"
        )
        text.append(f"workspace slices written to {written}")
    return "\n".join(text)
