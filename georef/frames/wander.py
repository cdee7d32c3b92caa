"""Applanix's wander frame and the quantities of an SBET record, from georef's NED navigation and FRD body.

Applanix (POSPac SBET and its ``smrmsg`` error file, docs/sbet.md) resolves the velocity in a *wander frame*:
x and y level, z **up**; at wander angle ``alpha = 0`` x points north and y west. A positive wander angle turns x
from north towards west (counter-clockwise seen from above), so the *platform heading*, measured clockwise from
the wander x axis, is ``true heading + alpha`` and ``true heading = platform heading - alpha`` (the relation
Applanix's readers apply; the header of JALBTCX-PFM-ABE/lib-charts FilePOSOutput.h states it). georef writes
``alpha = 0``: there is no wander mechanisation to report, and a zero wander angle makes the file read the same
under either sign convention a consumer may use.

Evidence for the axes (docs/sbet.md): in PDAL's test file ``test/data/sbet/2-points.sbet`` (a real POSPac
export) the z velocity equals the rate of the height (-0.031 m/s, height falling), so z is up, and the
y velocity has the opposite sign of the east velocity the positions give, so y is west.

The body frame is Applanix's and georef's: x forward, y right, z down; roll and pitch are the ZYX angles of
``C_b_n = Rz(yaw) Ry(pitch) Rx(roll)``. The SBET body accelerations are accelerations, gravity removed (the same
file's z acceleration is -0.30 m/s^2 in level motion, not the -9.8 m/s^2 an accelerometer reads):
``a_b = f_b + C_n_b g_n`` with the normal gravity ``g_n = (0, 0, g)`` down. The Coriolis and transport terms
(below 0.01 m/s^2 at aircraft speeds) are not removed.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from georef.frames.earth import normal_gravity
from georef.frames.rotations import wrap_pi

#: arc-minutes per radian: the unit of the attitude RMS in Applanix's smrmsg file
ARCMIN_PER_RAD = 60.0 * 180.0 / np.pi


def ned_to_wander(v_n: ArrayLike, wander: ArrayLike) -> np.ndarray:
    """A NED vector (N, 3) resolved in the wander frame (x, y level, z up; ``wander`` [rad] (N,) turns x from north
    towards west)."""
    v = np.asarray(v_n, dtype=float)
    a = np.asarray(wander, dtype=float)
    c, s = np.cos(a), np.sin(a)
    # x axis (cos a, -sin a, 0) and y axis (-sin a, -cos a, 0) in NED; z = up = -down
    x = c * v[..., 0] - s * v[..., 1]
    y = -s * v[..., 0] - c * v[..., 1]
    return np.stack([x, y, -v[..., 2]], axis=-1)


def platform_heading(true_heading: ArrayLike, wander: ArrayLike) -> np.ndarray:
    """Applanix's platform heading [rad] in (-pi, pi]: the true heading (clockwise from north) plus the wander
    angle [rad]."""
    return wrap_pi(np.asarray(true_heading, dtype=float) + np.asarray(wander, dtype=float))


def body_acceleration(specific_force_b: ArrayLike, C_b_n: ArrayLike, lat: ArrayLike, height: ArrayLike) -> np.ndarray:
    """Acceleration [m/s^2] (N, 3) along the body axes from the specific force [m/s^2] (N, 3) an accelerometer
    measures: ``f_b + C_n_b (0, 0, g)`` with the normal gravity at ``lat`` [rad], ``height`` [m]."""
    f = np.asarray(specific_force_b, dtype=float)
    g = normal_gravity(lat, height)
    # C_n_b (0, 0, g) is g times the last row of C_b_n
    return f + np.asarray(C_b_n, dtype=float)[..., 2, :] * np.asarray(g, dtype=float)[..., None]
