"""Workspace of the planar 3-RRR robot: the thesis's triple sweep and the largest rectangle.

The thesis (chapter 7, figs. 10-11) sweeps x, y and phi over a grid and checks every pose;
:func:`workspace_sweep` does that in one compiled loop (the same validity test as
:meth:`Rrr3.status`: reachable, outside both singularity margins, within the servo ranges), and
:func:`inscribed_rectangle` finds the largest axis-aligned rectangle of valid positions at one
orientation (the cursor calibration's default target area). :meth:`Rrr3.workspace` and
:meth:`Rrr3.inscribed_rectangle` call these. Pure math: plotting lives in
:mod:`motionbase.io.planar_plots`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from motionbase.errors import ConfigError
from motionbase.platform import _rrr3_kernels as _k
from motionbase.platform.rrr3_geometry import Rrr3Geometry

__all__ = ["PlanarWorkspace", "inscribed_rectangle", "workspace_sweep"]

_SQRT3 = math.sqrt(3.0)


class PlanarWorkspace(NamedTuple):
    """A workspace sweep over a grid (the thesis's triple loop), see :func:`workspace_sweep`.

    ``x`` (nx,), ``y`` (ny,) in m and ``phi`` (nphi,) in rad are the grid axes; ``status``
    (nx, ny, nphi) int8 holds the status word of every pose (0 = valid).
    """

    x: np.ndarray
    y: np.ndarray
    phi: np.ndarray
    status: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        """Boolean (nx, ny, nphi): the pose is reachable, non-singular and servo-valid."""
        return self.status == 0

    @property
    def total(self) -> np.ndarray:
        """Boolean (nx, ny): reachable with at least one orientation (thesis fig. 10)."""
        return self.valid.any(axis=2)

    def slice_at(self, phi: float) -> np.ndarray:
        """Boolean (nx, ny) at the grid orientation nearest ``phi`` rad (thesis fig. 11)."""
        return self.valid[:, :, int(np.argmin(np.abs(self.phi - phi)))]


def workspace_sweep(
    geometry: Rrr3Geometry,
    nx: int = 100,
    ny: int = 100,
    nphi: int = 73,
    *,
    x_range: tuple[float, float] | None = None,
    y_range: tuple[float, float] | None = None,
    phi_range: tuple[float, float] = (-math.pi, math.pi),
) -> PlanarWorkspace:
    """The thesis's triple sweep over x, y and phi (chapter 7), compiled.

    Parameters
    ----------
    geometry : Rrr3Geometry
    nx, ny, nphi : int
        Grid sizes (phi includes both ends of ``phi_range``: 73 gives 5 deg steps on
        -180..180 deg).
    x_range, y_range : (float, float), m, optional
        Default: the bounding box of the base triangle, grown to hold every position the
        platform can reach: within ``crank + rod + platform_side / sqrt(3)`` (to its
        centroid) of every motor. With longer links than the thesis's the workspace leaves
        the triangle's box (cranks of 0.07 m and rods of 0.14 m on its base: 3 cm below
        ``y = 0``), and a sweep of the box alone would cut it off.
    phi_range : (float, float), rad
    """
    base = np.asarray(geometry.base_points, dtype=float)
    r = geometry.crank + geometry.rod + geometry.platform_side / _SQRT3
    lo = np.minimum(base.min(axis=0), base.max(axis=0) - r)  # (the discs' intersection)
    hi = np.maximum(base.max(axis=0), base.min(axis=0) + r)
    xr = x_range if x_range is not None else (float(lo[0]), float(hi[0]))
    yr = y_range if y_range is not None else (float(lo[1]), float(hi[1]))
    xs = np.linspace(xr[0], xr[1], int(nx))
    ys = np.linspace(yr[0], yr[1], int(ny))
    ps = np.linspace(phi_range[0], phi_range[1], int(nphi))
    return PlanarWorkspace(xs, ys, ps, _k.status_grid(xs, ys, ps, geometry.packed()))


def inscribed_rectangle(
    geometry: Rrr3Geometry, phi: float = 0.0, *, n: int = 241
) -> tuple[float, float, float, float]:
    """Largest axis-aligned rectangle of valid positions at orientation ``phi`` (rad).

    Returns ``(x_min, x_max, y_min, y_max)`` in m. Found on an ``n x n`` grid over the base
    triangle's bounding box (largest rectangle of ones in a binary matrix), then shrunk by
    one grid step on every side so that its edges lie inside the valid region.

    Raises
    ------
    ConfigError
        If no rectangle of at least 4 x 4 grid points is valid at ``phi``.
    """
    L = geometry.base_side
    xs = np.linspace(0.0, L, n)
    ys = np.linspace(0.0, L * _SQRT3 / 2, n)
    ok = _k.status_grid(xs, ys, np.array([float(phi)]), geometry.packed())[:, :, 0] == 0
    best = (0, 0, 0, 0, 0)  # area, i0, i1, j0, j1 (inclusive grid indices)
    heights = [0] * n  # along x: run length of valid cells in y ending at row j
    okl = ok.tolist()
    for j in range(n):
        heights = [h + 1 if okl[i][j] else 0 for i, h in enumerate(heights)]
        stack: list[int] = []
        for i in range(n + 1):
            hcur = heights[i] if i < n else 0
            while stack and heights[stack[-1]] >= hcur:
                top = stack.pop()
                left = stack[-1] + 1 if stack else 0
                area = (i - left) * heights[top]
                if area > best[0]:
                    best = (area, left, i - 1, j - heights[top] + 1, j)
            stack.append(i)
    _, i0, i1, j0, j1 = best
    if i1 - i0 < 3 or j1 - j0 < 3:
        raise ConfigError(
            f"3-RRR {geometry.name!r}: no usable workspace rectangle at phi = {phi:g} rad "
            f"(fewer than 4 x 4 valid positions on a {n} x {n} grid over the base triangle; "
            "widen the servo ranges or check the geometry)"
        )
    return (xs[i0 + 1], xs[i1 - 1], ys[j0 + 1], ys[j1 - 1])
