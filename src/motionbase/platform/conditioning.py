"""How well a parallel platform's legs hold its pose: the conditioning of the legs' lines.

A leg whose ends are ball (or universal) joints pushes the platform only along its own line:
a force ``f u`` at the platform joint ``p`` (from the platform centre), that is, the wrench
``f [u, p x u]``. Six legs hold the platform when their six wrenches span every force and
moment. If the platform joints come together (a platform radius near zero, all joints near
one point) the moments ``p x u`` vanish and nothing holds the platform's rotations: it turns
freely about that point (a person on it tips it over), and the inverse kinematics, whose
actuator values hardly change with the rotation, reports almost any rotation as reachable.

The measure compares forces with moments through a length that does not depend on the
platform joints (the leg length): rows ``[u_i, (p_i x u_i) / length]``, ``1 / cond_2`` of
that 6x6 matrix, in [0, 1]. With it at ``c``, a moment ``M`` on the platform (say the
occupant's weight ``W`` leaning a leg length ``L`` off centre, ``M = W L``) can take leg
forces of up to about ``W / c``: 100 times the weight at ``c = 0.01``. Normalising the
moments by the platform radius instead (as the run-time ``conditioning`` of
:class:`~motionbase.platform.rus6.Rus6` does, for a measure that stays put when a platform is
scaled) hides the case: the moment and the normaliser shrink together.
"""

from __future__ import annotations

import numpy as np

__all__ = ["MIN_LINE_CONDITIONING", "line_conditioning"]

#: Below this, a geometry is refused at load: a leaning occupant would take leg forces of
#: more than 100 times their weight, and the rotations are practically unconstrained. The
#: shipped presets sit at 0.27 (``ceart``) and 0.20 (``seat``).
MIN_LINE_CONDITIONING = 0.01


def line_conditioning(joints: np.ndarray, directions: np.ndarray, length: float) -> float:
    """``1 / cond_2`` of the legs' lines, rotations scaled by ``length``.

    Parameters
    ----------
    joints : ndarray, shape (6, 3)
        Platform joints relative to the platform centre, m.
    directions : ndarray, shape (6, 3)
        Each leg's direction (any length, not zero) along its line, base axes.
    length : float
        The length that turns a moment into a force, m (> 0): the mean leg length.
    """
    u = np.asarray(directions, dtype=float)
    u = u / np.linalg.norm(u, axis=1)[:, None]
    moments = np.cross(np.asarray(joints, dtype=float), u) / length
    s = np.linalg.svd(np.hstack([u, moments]), compute_uv=False)
    if not np.isfinite(s).all() or s[0] == 0.0:
        return 0.0
    return float(s[-1] / s[0])
