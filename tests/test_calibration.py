"""Cursor calibration: the bi-quadratic map of eqs. 7.15-7.16, fitted by least squares."""

from __future__ import annotations

import numpy as np
import pytest

from motionbase.config import preset_path, write_toml
from motionbase.errors import ConfigError
from motionbase.platform import CursorCalibration, Rrr3, Rrr3Geometry

# A known bi-quadratic map in raw pixels (the thesis's window: 1310 x 715 px), coefficients
# chosen so that the window lands around the robot's workspace with visible curvature.
CX = [0.09, 6.1e-5, 2.0e-6, 3.0e-9, -4.0e-9, 5.0e-9, 1.0e-12, -2.0e-12, 3.0e-16]
CY = [0.12, 1.5e-6, -1.0e-4, -2.0e-9, 3.0e-9, 1.0e-8, -1.0e-12, 2.0e-12, -1.0e-15]


def truth(px: np.ndarray) -> np.ndarray:
    u, v = px[..., 0], px[..., 1]
    mono = [np.ones_like(u), u, v, u * v, u**2, v**2, u**2 * v, u * v**2, u**2 * v**2]
    return np.stack([sum(c * m for c, m in zip(C, mono, strict=True)) for C in (CX, CY)], -1)


def grid(n: int, w: float = 1310.0, h: float = 715.0) -> np.ndarray:
    U, V = np.meshgrid(np.linspace(0, w, n), np.linspace(0, h, n))
    return np.stack([U.ravel(), V.ravel()], -1)


def test_recovers_known_biquadratic_map_from_nine_points():
    px = grid(3)  # the thesis's m1..m9 layout
    cal = CursorCalibration.fit(px, truth(px))
    rng = np.random.default_rng(0)
    test_px = rng.uniform([0, 0], [1310, 715], (500, 2))
    np.testing.assert_allclose(cal(test_px), truth(test_px), atol=1e-12)
    assert cal.residual < 1e-14 and cal.n_points == 9
    x, y = cal.map_one(*test_px[0])
    np.testing.assert_allclose([x, y], truth(test_px[0]), atol=1e-12)
    assert cal(test_px.reshape(50, 10, 2)).shape == (50, 10, 2)


def test_least_squares_on_more_points_and_large_residual_when_inconsistent():
    px = grid(5)
    pts = truth(px)
    good = CursorCalibration.fit(px, pts)
    assert good.residual < 1e-14 and good.n_points == 25
    bad_pts = pts.copy()
    bad_pts[7] += [0.01, -0.01]  # one pair 14 mm off: no bi-quadratic map fits all
    bad = CursorCalibration.fit(px, bad_pts)
    assert bad.residual > 1e-3
    assert bad.max_residual > bad.residual
    # noise at the 0.1 mm level gives a residual at that level, not more
    rng = np.random.default_rng(1)
    noisy = CursorCalibration.fit(px, pts + rng.normal(0, 1e-4, pts.shape))
    assert 2e-5 < noisy.residual < 2e-4


def test_degenerate_layouts_are_refused():
    line = np.stack([np.linspace(0, 100, 9), np.linspace(0, 50, 9)], -1)
    with pytest.raises(ConfigError, match="cannot determine"):
        CursorCalibration.fit(line, truth(line))
    two_cols = np.array([[u, v] for u in (0, 100) for v in np.linspace(0, 80, 5)])
    with pytest.raises(ConfigError, match="3 distinct columns"):
        CursorCalibration.fit(two_cols, truth(two_cols))
    with pytest.raises(ConfigError, match="at least 9"):
        CursorCalibration.fit(grid(2), truth(grid(2)))
    with pytest.raises(ConfigError, match="both be"):
        CursorCalibration.fit(grid(3), truth(grid(3))[:, :1])
    flat = np.array([[u, 5.0] for u in range(9)])
    with pytest.raises(ConfigError, match="spread"):
        CursorCalibration.fit(flat, truth(flat))


def test_toml_round_trip(tmp_path):
    px = grid(4)
    cal = CursorCalibration.fit(px, truth(px) + 1e-4 * np.sin(px))
    p = tmp_path / "cal.toml"
    cal.to_toml(p)
    back = CursorCalibration.from_toml(p)
    assert back == cal
    (tmp_path / "bad.toml").write_text("[calibration]\ncoef_x = [1, 2]\n")
    with pytest.raises(ConfigError, match="missing field|coef_x"):
        CursorCalibration.from_toml(tmp_path / "bad.toml")


def test_a_file_whose_map_cannot_be_the_workspace_is_refused(tmp_path):
    """A calibration file edited by hand: a pixel box a fraction of a pixel wide (the map
    divided by it gave NaN targets, every tick held) or coefficients not in metres (every
    target clamped) is refused when read, naming the file and the field."""
    px = grid(3)
    good = CursorCalibration.fit(px, truth(px)).to_dict()
    cases = [
        ({"pixel_scale": [1e-320, 300.0]}, "'pixel_scale': must be at least 0.5 pixels"),
        ({"pixel_scale": [0.2, 300.0]}, "'pixel_scale': must be at least 0.5 pixels"),
        ({"coef_x": [1e300] * 9}, "maps its own pixels to"),
        ({"coef_y": [0.0, 4.0e3] + [0.0] * 7}, "maps its own pixels to 4e+03 m"),  # mm
        ({"coef_x": [float("nan")] + good["coef_x"][1:]}, "every value must be finite"),
    ]
    path = tmp_path / "cal.toml"
    for change, needle in cases:
        write_toml(path, {"calibration": {**good, **change}})
        with pytest.raises(ConfigError, match="cal.toml") as exc:
            CursorCalibration.from_toml(path)
        assert needle in str(exc.value), (change, str(exc.value))
        assert "\n" not in str(exc.value)
    # another kind of file given as the calibration (it said "unknown field 'description'")
    with pytest.raises(ConfigError, match=r"washout parameter file .*not a cursor calibration"):
        CursorCalibration.from_toml(preset_path("washout", "default"))
    # a fit from pixels spread over less than a pixel is refused the same way
    tiny = grid(3) * 1e-3
    with pytest.raises(ConfigError, match="at least a pixel"):
        CursorCalibration.fit(tiny, truth(grid(3)))
    # and one from points in millimetres
    with pytest.raises(ConfigError, match="maps its own pixels to"):
        CursorCalibration.fit(px, truth(px) * 1e3)


def test_default_maps_window_onto_valid_rectangle_with_y_down():
    rrr3 = Rrr3(Rrr3Geometry.preset("udesc"))
    cal = CursorCalibration.default(rrr3, 800, 600)
    x0, x1, y0, y1 = rrr3.inscribed_rectangle(0.0)
    np.testing.assert_allclose(cal([0, 0]), [x0, y1], atol=1e-12)  # top-left: y max
    np.testing.assert_allclose(cal([800, 600]), [x1, y0], atol=1e-12)
    np.testing.assert_allclose(cal([400, 300]), [(x0 + x1) / 2, (y0 + y1) / 2], atol=1e-12)
    # moving the cursor down lowers y
    assert cal([100, 400])[1] < cal([100, 200])[1]
    px = grid(25, 800, 600)
    xy = cal(px)
    poses = np.concatenate([xy, np.zeros((len(xy), 1))], axis=1)
    assert rrr3.reachable(poses).all()


def test_a_pixel_off_the_calibrated_screen_is_taken_at_its_edge():
    """A 9-point calibration measured on the robot (positions read to about half a
    millimetre) is a bi-quadratic with some curvature; beyond its points it bent back, so
    a gaze moving on off the screen (an eye tracker reports such points) moved the robot
    back, and a tracker's "lost" value (-32768, -32768) went anywhere. Off the screen the
    map now holds the screen's edge: monotonic, and bounded by the edge's points."""
    rrr3 = Rrr3(Rrr3Geometry.preset("udesc"))
    x0, x1, y0, y1 = rrr3.inscribed_rectangle(0.0)
    px = grid(3)
    ideal = np.stack([x0 + px[:, 0] / 1310 * (x1 - x0), y1 - px[:, 1] / 715 * (y1 - y0)], -1)
    measured = ideal + np.random.default_rng(3).normal(0.0, 0.0005, ideal.shape)
    cal = CursorCalibration.fit(px, measured)
    # rays from the screen's centre through its corners and mid-edges to three half-screens
    # beyond: the robot's progress along each (as the ideal map moves it) never turns
    # back, and off the screen it holds the point where the ray left it
    k = np.linspace(0.0, 3.0, 601)[:, None]  # (k = 1: the screen's edge)
    scale = np.array([(x1 - x0) / 1310, -(y1 - y0) / 715])  # the ideal map's m per pixel
    rays = []
    for angle in np.radians(np.arange(0, 360, 45)):
        d = np.array([655 * np.cos(angle), 357.5 * np.sin(angle)])
        d /= np.abs(d / [655, 357.5]).max()  # to the edge or corner at k = 1
        rays.append((d, cal(np.array([655.0, 357.5]) + k * d)))
    for d, xy in rays:
        progress = (xy - xy[0]) @ (scale * d)
        assert np.all(np.diff(progress) >= 0.0), f"turns back toward {d.round()} px"
    for d, xy in rays:
        assert np.abs(xy[200:] - xy[200]).max() <= 1e-15  # (k[200] = 1)
        np.testing.assert_allclose(cal.map_one(*(np.array([655.0, 357.5]) + 3 * d)), xy[-1])
    np.testing.assert_allclose(cal([-32768.0, -32768.0]), cal([0.0, 0.0]), rtol=0, atol=1e-15)
    # on the screen, the fit itself (its own points)
    np.testing.assert_allclose(cal(px), measured, atol=1e-12)
