"""Cursor-to-workspace calibration: the bi-quadratic map of the thesis (eqs. 7.13-7.21).

A cursor position ``(u, v)`` in pixels maps to a platform position ``(x, y)`` in metres by

    x = C1 + C2 u + C3 v + C4 u v + C5 u^2 + C6 v^2 + C7 u^2 v + C8 u v^2 + C9 u^2 v^2   (7.15)
    y = C10 + C11 u + ... + C18 u^2 v^2                                                   (7.16)

Pixel axes are the screen's: ``u`` to the right and ``v`` **down** (row 0 at the top), so a
map to the base frame (y up) has a negative ``v`` coefficient; the polynomial absorbs the flip.

The thesis solves the 9 x 9 system of 9 point pairs by inverting the matrix with raw pixel
values (monomials up to ``u^2 v^2 ~ 1e12``, an ill-conditioned system; its printed
coefficients do not reproduce its own points). Here the pixels are first normalised to about
[-1, 1] (centre and half-range of the calibration pixels, stored with the map), the
coefficients come from least squares over 9 or more pairs, and the fit is refused when the
normalised design matrix is rank deficient or badly conditioned (points on a line, repeated
points). ``residual`` is the RMS fit error in metres (zero for 9 exact points; large when the
pairs are inconsistent with any bi-quadratic map).

The map holds over the box of the fitted pixels (the screen the points were taken on): a
pixel outside it is taken at the box's edge. A bi-quadratic is not extrapolated: beyond its
points it bends back, so that a cursor moving on off the screen moved the robot back.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from motionbase.config import (
    as_array,
    as_float,
    check_keys,
    describe_file_kind,
    file_kind,
    read_toml,
    write_toml,
)
from motionbase.errors import ConfigError

if TYPE_CHECKING:
    from motionbase.platform.rrr3 import Rrr3

__all__ = ["CursorCalibration", "MAX_CONDITION", "MAX_REACH_M", "MIN_PIXEL_SCALE"]

#: Largest condition number accepted for the normalised 9-column design matrix.
MAX_CONDITION = 1e6
#: Smallest half-spread of the fitted pixels, pixels (below it the map divides by ~0).
MIN_PIXEL_SCALE = 0.5
#: Largest distance from the base origin the map may give its own pixel box, m (a planar
#: robot's workspace is decimetres; more means coefficients in the wrong unit).
MAX_REACH_M = 10.0


def _features(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Monomials of eq. 7.15 in its order: 1, u, v, uv, u^2, v^2, u^2 v, u v^2, u^2 v^2."""
    uu, vv = u * u, v * v
    return np.stack([np.ones_like(u), u, v, u * v, uu, vv, uu * v, u * vv, uu * vv], axis=-1)


@dataclass(frozen=True)
class CursorCalibration:
    """A fitted bi-quadratic map from cursor pixels to workspace metres.

    Attributes
    ----------
    coef_x, coef_y : tuple of 9 float
        Coefficients of eqs. 7.15 and 7.16 (``C1..C9`` and ``C10..C18``) for the *normalised*
        pixels ``((u - center_u) / scale_u, (v - center_v) / scale_v)``, m.
    pixel_center, pixel_scale : tuple of 2 float
        The normalisation, pixels.
    residual : float
        RMS of the fit's position errors over the calibration pairs, m.
    max_residual : float
        Largest position error over the calibration pairs, m.
    n_points : int
        Number of point pairs fitted.
    """

    coef_x: tuple[float, ...]
    coef_y: tuple[float, ...]
    pixel_center: tuple[float, float]
    pixel_scale: tuple[float, float]
    residual: float = 0.0
    max_residual: float = 0.0
    n_points: int = 0

    # -- fitting ---------------------------------------------------------------------------
    @classmethod
    def fit(
        cls, pixels: Any, points: Any, *, max_condition: float = MAX_CONDITION
    ) -> CursorCalibration:
        """Least-squares fit of eqs. 7.15-7.16 to point pairs.

        Parameters
        ----------
        pixels : array_like (N, 2)
            Cursor positions ``(u, v)``, pixels (u right, v down), N >= 9.
        points : array_like (N, 2)
            The matching platform positions ``(x, y)`` in the base frame, m.
        max_condition : float
            Refuse the fit when the normalised design matrix's condition number exceeds this.

        Raises
        ------
        ConfigError
            Fewer than 9 pairs, mismatched shapes, non-finite values, or a degenerate layout.
        """
        px = np.asarray(pixels, dtype=float)
        pt = np.asarray(points, dtype=float)
        if px.ndim != 2 or px.shape[1] != 2 or pt.shape != px.shape:
            raise ConfigError(
                f"calibration: pixels and points must both be (N, 2), got {px.shape} and {pt.shape}"
            )
        if px.shape[0] < 9:
            raise ConfigError(
                f"calibration: need at least 9 point pairs for the bi-quadratic map, got "
                f"{px.shape[0]} (add points, e.g. a 3 x 3 grid)"
            )
        if not (np.isfinite(px).all() and np.isfinite(pt).all()):
            raise ConfigError("calibration: pixels and points must be finite")
        lo, hi = px.min(axis=0), px.max(axis=0)
        center = (lo + hi) / 2
        scale = (hi - lo) / 2
        if not (scale >= MIN_PIXEL_SCALE).all():
            raise ConfigError(
                "calibration: the pixels must spread over at least a pixel in both u and v "
                f"(they spread over {2 * scale[0]:g} x {2 * scale[1]:g})"
            )
        M = _features((px[:, 0] - center[0]) / scale[0], (px[:, 1] - center[1]) / scale[1])
        sv = np.linalg.svd(M, compute_uv=False)
        cond = sv[0] / sv[-1] if sv[-1] > 0 else np.inf
        if not cond <= max_condition:
            raise ConfigError(
                f"calibration: the pixel layout cannot determine a bi-quadratic map (condition "
                f"number {cond:.3g} > {max_condition:.3g}); use at least 3 distinct columns "
                "and 3 distinct rows of points, e.g. a 3 x 3 grid"
            )
        coef, *_ = np.linalg.lstsq(M, pt, rcond=None)
        err = np.linalg.norm(M @ coef - pt, axis=1)
        return cls(
            coef_x=tuple(float(c) for c in coef[:, 0]),
            coef_y=tuple(float(c) for c in coef[:, 1]),
            pixel_center=(float(center[0]), float(center[1])),
            pixel_scale=(float(scale[0]), float(scale[1])),
            residual=float(np.sqrt(np.mean(err**2))),
            max_residual=float(err.max()),
            n_points=int(px.shape[0]),
        )._checked("calibration")

    @classmethod
    def default(cls, rrr3: Rrr3, width_px: int, height_px: int) -> CursorCalibration:
        """Map a ``width_px x height_px`` window onto the largest valid rectangle at phi = 0.

        The window's top-left pixel ``(0, 0)`` goes to the rectangle's ``(x_min, y_max)`` and
        the bottom-right ``(width_px, height_px)`` to ``(x_max, y_min)``: pixel v points down,
        base y up. The map is linear (fitted from the 3 x 3 grid of corners and mid-points);
        a window with another aspect ratio than the rectangle is stretched.
        """
        w = as_float("calibration", "width_px", width_px, min_value=1.0)
        h = as_float("calibration", "height_px", height_px, min_value=1.0)
        x0, x1, y0, y1 = rrr3.inscribed_rectangle(0.0)
        fu, fv = np.meshgrid([0.0, 0.5, 1.0], [0.0, 0.5, 1.0])
        pixels = np.stack([fu.ravel() * w, fv.ravel() * h], axis=-1)
        points = np.stack([x0 + fu.ravel() * (x1 - x0), y1 - fv.ravel() * (y1 - y0)], axis=-1)
        return cls.fit(pixels, points)

    def _checked(self, source: str) -> CursorCalibration:
        """This map, if its pixel box is at least a pixel wide and it maps that box
        (its 3 x 3 grid) to workspace-sized metres; else a ConfigError naming ``source``."""
        scale = np.array(self.pixel_scale)
        if not (scale >= MIN_PIXEL_SCALE).all():
            raise ConfigError(
                f"{source}: field 'pixel_scale': must be at least {MIN_PIXEL_SCALE} pixels "
                f"(half the spread of the fitted pixels), got {scale.tolist()}"
            )
        unit = np.stack(np.meshgrid([-1.0, 0.0, 1.0], [-1.0, 0.0, 1.0]), axis=-1).reshape(-1, 2)
        with np.errstate(all="ignore"):
            reach = np.abs(self(np.array(self.pixel_center) + unit * scale)).max()
        if not reach <= MAX_REACH_M:
            raise ConfigError(
                f"{source}: maps its own pixels to {reach:.3g} m from the base origin, not a "
                f"planar robot's workspace (at most {MAX_REACH_M:g} m); the points are metres: "
                "fit it again (CursorCalibration.fit)"
            )
        return self

    # -- evaluation --------------------------------------------------------------------------
    def __call__(self, pixels: Any) -> np.ndarray:
        """Platform positions (..., 2), m, of cursor pixels (..., 2)."""
        px = np.asarray(pixels, dtype=float)
        if px.ndim == 0 or px.shape[-1] != 2:
            raise ConfigError(f"calibration: pixels must have shape (..., 2), got {px.shape}")
        F = _features(
            np.clip((px[..., 0] - self.pixel_center[0]) / self.pixel_scale[0], -1.0, 1.0),
            np.clip((px[..., 1] - self.pixel_center[1]) / self.pixel_scale[1], -1.0, 1.0),
        )
        return np.stack([F @ np.asarray(self.coef_x), F @ np.asarray(self.coef_y)], axis=-1)

    def map_one(self, u: float, v: float) -> tuple[float, float]:
        """Scalar fast path of ``__call__``: ``(x, y)`` in m for one cursor pixel."""
        # (in this order a NaN stays NaN, as through np.clip)
        a = min(max((u - self.pixel_center[0]) / self.pixel_scale[0], -1.0), 1.0)
        b = min(max((v - self.pixel_center[1]) / self.pixel_scale[1], -1.0), 1.0)
        aa, bb = a * a, b * b
        f = (1.0, a, b, a * b, aa, bb, aa * b, a * bb, aa * bb)
        cx, cy = self.coef_x, self.coef_y
        x = (
            cx[0] * f[0] + cx[1] * f[1] + cx[2] * f[2] + cx[3] * f[3] + cx[4] * f[4]
            + cx[5] * f[5] + cx[6] * f[6] + cx[7] * f[7] + cx[8] * f[8]
        )  # fmt: skip
        y = (
            cy[0] * f[0] + cy[1] * f[1] + cy[2] * f[2] + cy[3] * f[3] + cy[4] * f[4]
            + cy[5] * f[5] + cy[6] * f[6] + cy[7] * f[7] + cy[8] * f[8]
        )  # fmt: skip
        return x, y

    # -- files -----------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """Plain data; :meth:`from_dict` inverts it exactly."""
        return {
            "kind": "biquadratic",
            "coef_x": list(self.coef_x),
            "coef_y": list(self.coef_y),
            "pixel_center": list(self.pixel_center),
            "pixel_scale": list(self.pixel_scale),
            "residual": self.residual,
            "max_residual": self.max_residual,
            "n_points": self.n_points,
        }

    @classmethod
    def from_dict(cls, data: Any, *, source: str = "calibration") -> CursorCalibration:
        """Build from :meth:`to_dict`'s layout; bad or missing fields are ConfigErrors."""
        if not isinstance(data, dict):
            raise ConfigError(f"{source}: expected a table")
        keys = ("kind", "coef_x", "coef_y", "pixel_center", "pixel_scale", "residual",
                "max_residual", "n_points")  # fmt: skip
        check_keys(source, data, keys, required=keys[1:5])
        if data.get("kind", "biquadratic") != "biquadratic":
            raise ConfigError(f"{source}: field 'kind': only 'biquadratic' is known")
        scale = as_array(source, "pixel_scale", data["pixel_scale"], 2)
        n = data.get("n_points", 0)
        if isinstance(n, bool) or not isinstance(n, int) or n < 0:
            raise ConfigError(f"{source}: field 'n_points': expected a count, got {n!r}")
        return cls(
            coef_x=tuple(as_array(source, "coef_x", data["coef_x"], 9).tolist()),
            coef_y=tuple(as_array(source, "coef_y", data["coef_y"], 9).tolist()),
            pixel_center=tuple(as_array(source, "pixel_center", data["pixel_center"], 2).tolist()),
            pixel_scale=tuple(scale.tolist()),
            residual=as_float(source, "residual", data.get("residual", 0.0), min_value=0.0),
            max_residual=as_float(
                source, "max_residual", data.get("max_residual", 0.0), min_value=0.0
            ),
            n_points=n,
        )._checked(source)

    def to_toml(self, path: str | Path) -> None:
        """Write to TOML under a ``[calibration]`` table."""
        write_toml(path, {"calibration": self.to_dict()})

    @classmethod
    def from_toml(cls, path: str | Path) -> CursorCalibration:
        """Read a file written by :meth:`to_toml`."""
        data = read_toml(path)
        kind = file_kind(data) if "calibration" not in data else None
        if kind is not None:
            raise ConfigError(
                f"{path}: {describe_file_kind(kind)}, not a cursor calibration (a "
                "[calibration] table)"
            )
        check_keys(str(path), data, ("calibration",), required=("calibration",))
        return cls.from_dict(data["calibration"], source=f"{path} [calibration]")
