"""Plots and the text report of the planar 3-RRR workspace (matplotlib, Agg, no display).

The sweep itself is pure math in :meth:`motionbase.platform.rrr3.Rrr3.workspace`; this module
only draws it (the thesis's fig. 10, total workspace, and fig. 11, constant orientation) and
writes the file.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from motionbase.errors import ConfigError
from motionbase.io.workspace_plots import plot_format, save_figure
from motionbase.platform.robot import load_geometry
from motionbase.platform.rrr3 import Rrr3
from motionbase.platform.rrr3_workspace import PlanarWorkspace

__all__ = ["planar_workspace_figure", "plot_planar_workspace", "planar_workspace_report"]


def plot_planar_workspace(
    rrr3: Rrr3,
    ws: PlanarWorkspace,
    path: str | Path,
    *,
    phi: float = 0.0,
    rectangle: tuple[float, float, float, float] | None = None,
    title: str = "3-RRR workspace",
) -> Path:
    """Draw the total workspace and the constant-orientation slice to a file.

    Parameters
    ----------
    rrr3, ws, phi, rectangle, title :
        As for :func:`planar_workspace_figure`.
    path : str or Path
        Output file: ``.png``, ``.svg`` or ``.pdf`` (the format follows the extension).

    Returns
    -------
    Path
        The file written.
    """
    plot_format(path)
    fig = planar_workspace_figure(rrr3, ws, phi=phi, rectangle=rectangle, title=title)
    return save_figure(fig, path)


def planar_workspace_figure(
    rrr3: Rrr3,
    ws: PlanarWorkspace,
    *,
    phi: float = 0.0,
    rectangle: tuple[float, float, float, float] | None = None,
    title: str = "3-RRR workspace",
) -> Any:
    """The figure of the total workspace and the constant-orientation slice, with a legend.

    Parameters
    ----------
    rrr3 : Rrr3
        The robot (for the base triangle, home and a sample configuration).
    ws : PlanarWorkspace
        A sweep from :meth:`Rrr3.workspace`.
    phi : float
        Orientation of the slice, rad (the grid's nearest value is used).
    rectangle : (x_min, x_max, y_min, y_max), m, optional
        Drawn on the slice (the cursor calibration's default target rectangle).
    title : str
        Figure title.

    Returns
    -------
    matplotlib.figure.Figure
        On an Agg canvas (no display).
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.colors import ListedColormap
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch

    fig = Figure(figsize=(12, 5.8), dpi=110)
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 2)
    cmap = ListedColormap(["#f2f2f2", "#4c8bd6"])
    k = int(np.argmin(np.abs(ws.phi - phi)))
    counts = ws.valid.sum(axis=2)
    panels = [
        (
            counts / max(1, counts.max()),
            f"total workspace (fig. 10): valid orientations\n(of {ws.phi.size} in "
            f"{math.degrees(ws.phi[0]):.0f}..{math.degrees(ws.phi[-1]):.0f} deg, relative)",
        ),
        (
            ws.valid[:, :, k].astype(float),
            f"constant orientation phi = {math.degrees(ws.phi[k]):.1f} deg (fig. 11)",
        ),
    ]
    A = rrr3.geometry.base_points
    tri = np.vstack([A, A[:1]])
    for n, (ax, (img, sub)) in enumerate(zip(axes, panels, strict=True)):
        if n == 0:
            mesh = ax.pcolormesh(ws.x, ws.y, img.T, cmap="Blues", vmin=0, vmax=1, shading="nearest")
            bar = fig.colorbar(mesh, ax=ax, fraction=0.046, pad=0.04)
            bar.set_label("share of orientations valid")
        else:
            ax.pcolormesh(ws.x, ws.y, img.T, cmap=cmap, vmin=0, vmax=1, shading="nearest")
        ax.plot(tri[:, 0], tri[:, 1], "k-", lw=0.8, label="base triangle")
        ax.plot(A[:, 0], A[:, 1], "ks", ms=6, ls="none", label="motors (crank pivots)")
        ax.plot(rrr3.home[0], rrr3.home[1], "r+", ms=12, ls="none", label="home")
        ax.set_xlabel("x, m")
        ax.set_ylabel("y, m")
        ax.set_title(sub, fontsize=9)
        ax.set_aspect("equal")
    # the robot at home on the slice
    jp = rrr3.joint_points(rrr3.home)
    ax = axes[1]
    for i in range(3):
        ax.plot(
            *np.array([jp.A[i], jp.B[i], jp.C[i]]).T,
            "-o",
            color="#444444",
            ms=3,
            lw=1.2,
            label="cranks and rods at home" if i == 0 else "_nolegend_",
        )
    ax.fill(*jp.C.T, facecolor="none", edgecolor="#e07b39", lw=1.5, label="platform at home")
    if rectangle is not None:
        x0, x1, y0, y1 = rectangle
        ax.plot(
            [x0, x1, x1, x0, x0],
            [y0, y0, y1, y1, y0],
            "g--",
            lw=1.2,
            label="largest rectangle (cursor calibration target)",
        )
    handles, labels = ax.get_legend_handles_labels()
    handles.insert(0, Patch(facecolor=cmap(1.0), label="valid pose"))
    labels.insert(0, "valid pose")
    fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=8, frameon=False)
    fig.suptitle(f"{title}: valid poses (reachable, non-singular, servo range) in blue")
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    return fig


def planar_workspace_report(
    geometry: str | Path | None = None,
    plot: str | Path | None = None,
    *,
    nx: int = 100,
    ny: int = 100,
    nphi: int = 73,
) -> str:
    """The ``motionbase workspace --planar`` job: sweep, summarise, optionally plot.

    Parameters
    ----------
    geometry : str or Path, optional
        A 3-RRR preset name (``udesc``, ``udesc_symmetric``) or a TOML path; default
        :data:`~motionbase.config.DEFAULT_RRR3`, as for every command.
    plot : str or Path, optional
        File (``.png``, ``.svg`` or ``.pdf``) to draw the total workspace and the phi = 0
        slice to; another extension is refused before the sweep.
    nx, ny, nphi : int
        Sweep grid (over the base triangle's bounding box and -180..180 deg).

    Returns
    -------
    str
        The summary, ready to print.
    """
    if plot is not None:
        plot_format(plot)
    _, g = load_geometry(geometry, planar=True)  # (a 6-DOF robot: "drop --planar", as fly)
    rrr3 = Rrr3(g)
    t0 = time.perf_counter()
    ws = rrr3.workspace(nx, ny, nphi)
    dt = time.perf_counter() - t0
    cell = (ws.x[1] - ws.x[0]) * (ws.y[1] - ws.y[0])
    total, flat = ws.total, ws.slice_at(0.0)

    def extent(mask: np.ndarray) -> str:
        if not mask.any():
            return "empty"
        xi, yi = np.nonzero(mask)
        return (
            f"x {ws.x[xi.min()]:.4f}..{ws.x[xi.max()]:.4f} m, "
            f"y {ws.y[yi.min()]:.4f}..{ws.y[yi.max()]:.4f} m"
        )

    try:
        rect: tuple[float, float, float, float] | None = rrr3.inscribed_rectangle(0.0)
    except ConfigError:  # a workspace too small for one: said, not a failure of the sweep
        rect = None
    phis = np.degrees(ws.phi[ws.valid.any(axis=(0, 1))])
    lines = [
        f"3-RRR robot {g.name!r}: L = {g.base_side} m, a = {g.crank} m, b = {g.rod} m, "
        f"h = {g.platform_side} m, modes {list(g.modes)}",
        f"sweep {nx} x {ny} x {nphi} poses in {dt * 1e3:.0f} ms",
        f"total workspace (any phi): {total.sum() * cell * 1e4:.1f} cm^2, {extent(total)}",
        f"phi = 0 slice: {flat.sum() * cell * 1e4:.1f} cm^2, {extent(flat)}",
        f"orientations reachable somewhere: {phis.min():.0f}..{phis.max():.0f} deg"
        if phis.size
        else "no valid orientation",
        f"largest rectangle at phi = 0: x {rect[0]:.4f}..{rect[1]:.4f} m, "
        f"y {rect[2]:.4f}..{rect[3]:.4f} m"
        if rect is not None
        else "largest rectangle at phi = 0: none (fewer than 4 x 4 valid positions on its "
        "grid: the cursor calibration has no default target rectangle)",
    ]
    if plot is not None:
        written = plot_planar_workspace(rrr3, ws, plot, rectangle=rect, title=f"3-RRR {g.name}")
        lines.append(f"workspace plot written to {written}")
    return "\n".join(lines)
