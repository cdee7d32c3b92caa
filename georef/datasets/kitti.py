"""The KITTI car log that ships in the gtsam wheel, and a GNSS-outage protocol scored on it.

Files (``gtsam/Data`` inside the installed ``gtsam`` package, used by GTSAM's ``IMUKittiExampleGPS.py``):

* ``KittiEquivBiasedImu.txt``: ``Time dt accelX accelY accelZ omegaX omegaY omegaZ``, about 100 Hz, seconds,
  m/s^2 and rad/s in the OXTS unit's axes: x forward, y left, z up. The first row's ``dt`` is a placeholder
  (it equals the time) and the second row follows it 1.9 s later;
* ``KittiGps_converted.txt``: ``Time,X,Y,Z`` at 1 Hz, metres in a local frame with X east, Y north, Z up.

georef's body frame is forward-right-down, so ``y`` and ``z`` change sign; the local east/north/up fixes are
placed on the WGS84 ellipsoid with a tangent plane at Karlsruhe (49.0108 N, 8.4241 E, 115 m), where KITTI was
recorded. The absolute place only sets gravity and Earth rate; over the 1 km drive the tangent plane departs
from the ellipsoid by under 0.1 m, the same for the fixes and for the scoring.

The outage protocol: from the first fix, every 60 s the last 20 s of fixes are withheld
(``(t - t0) mod 60 >= 40``). ``georef fuse`` runs on the remaining fixes; it is scored by the horizontal RMS
of its IMU position at the withheld fixes' times against those fixes, next to the same figure for linear
interpolation of the remaining fixes (what a user without an INS would do).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from georef.frames import C_e_n, C_n_e, ecef_to_geodetic, geodetic_to_ecef
from georef.timing import GnssEpochs

#: Karlsruhe, where the KITTI sequences were recorded: latitude, longitude [deg], ellipsoidal height [m]
KITTI_ORIGIN = (49.0108, 8.4241, 115.0)
#: FLU (OXTS) -> FRD (georef body axes)
FLU_TO_FRD = np.array([1.0, -1.0, -1.0])
OUTAGE_PERIOD_S = 60.0
OUTAGE_LENGTH_S = 20.0


def kitti_folder() -> Path:
    """The ``Data`` folder of the installed gtsam package (raises ``FileNotFoundError`` if it has no KITTI log)."""
    import importlib.util

    spec = importlib.util.find_spec("gtsam")
    if spec is None or not spec.submodule_search_locations:
        raise FileNotFoundError("gtsam is not installed; its wheel carries the KITTI log")
    folder = Path(next(iter(spec.submodule_search_locations))) / "Data"
    if not (folder / "KittiEquivBiasedImu.txt").exists():
        raise FileNotFoundError(f"no KITTI log in {folder}")
    return folder


@dataclass
class KittiLog:
    """The KITTI log in georef's units and axes: IMU time [s], gyro [rad/s] and specific force [m/s^2] (N, 3)
    in FRD; GNSS fixes [s] with local east/north/up [m] and on the ellipsoid."""

    time: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    gnss_time: np.ndarray
    gnss_enu: np.ndarray
    gnss: GnssEpochs


def enu_to_geodetic(enu: np.ndarray, origin: tuple[float, float, float] = KITTI_ORIGIN) -> np.ndarray:
    """Local east/north/up [m] (N, 3) on the tangent plane at ``origin`` -> latitude, longitude [deg], height [m]."""
    lat0, lon0 = np.radians(origin[0]), np.radians(origin[1])
    r0 = geodetic_to_ecef(lat0, lon0, origin[2])
    ned = np.stack([enu[:, 1], enu[:, 0], -enu[:, 2]], -1)
    lat, lon, h = ecef_to_geodetic(r0 + ned @ C_n_e(lat0, lon0).T)
    return np.stack([np.degrees(lat), np.degrees(lon), h], -1)


def geodetic_to_enu(lat_deg: np.ndarray, lon_deg: np.ndarray, height: np.ndarray,
                    origin: tuple[float, float, float] = KITTI_ORIGIN) -> np.ndarray:
    """The inverse of :func:`enu_to_geodetic`: east/north/up [m] (N, 3) on the tangent plane at ``origin``."""
    lat0, lon0 = np.radians(origin[0]), np.radians(origin[1])
    r0 = geodetic_to_ecef(lat0, lon0, origin[2])
    r = geodetic_to_ecef(np.radians(lat_deg), np.radians(lon_deg), height)
    ned = (r - r0) @ C_e_n(lat0, lon0).T
    return np.stack([ned[:, 1], ned[:, 0], -ned[:, 2]], -1)


def load_kitti(folder: Path | None = None) -> KittiLog:
    """Read the KITTI IMU and GNSS files (the IMU's first row, whose ``dt`` is a placeholder, is kept)."""
    folder = folder or kitti_folder()
    imu = np.loadtxt(folder / "KittiEquivBiasedImu.txt", skiprows=1)
    fixes = np.loadtxt(folder / "KittiGps_converted.txt", skiprows=1, delimiter=",")
    time = imu[:, 0]
    accel = imu[:, 2:5] * FLU_TO_FRD
    gyro = imu[:, 5:8] * FLU_TO_FRD
    geo = enu_to_geodetic(fixes[:, 1:4])
    gnss = GnssEpochs(time=fixes[:, 0], lat_deg=geo[:, 0], lon_deg=geo[:, 1], height=geo[:, 2],
                      line=np.arange(2, len(fixes) + 2), repeated=np.zeros(len(fixes), bool))
    return KittiLog(time=time, gyro=gyro, accel=accel, gnss_time=fixes[:, 0], gnss_enu=fixes[:, 1:4], gnss=gnss)


def withheld(gnss_time: np.ndarray, period: float = OUTAGE_PERIOD_S, length: float = OUTAGE_LENGTH_S) -> np.ndarray:
    """Fixes withheld by the protocol: the last ``length`` s of every ``period`` s from the first fix."""
    return np.mod(gnss_time - gnss_time[0], period) >= period - length


def subset(gnss: GnssEpochs, keep: np.ndarray) -> GnssEpochs:
    """The fixes ``keep`` (boolean mask) of ``gnss``."""
    return GnssEpochs(time=gnss.time[keep], lat_deg=gnss.lat_deg[keep], lon_deg=gnss.lon_deg[keep],
                      height=gnss.height[keep], line=gnss.line[keep], repeated=gnss.repeated[keep],
                      sigma_neu=None if gnss.sigma_neu is None else gnss.sigma_neu[keep])


@dataclass
class OutageScore:
    """Horizontal RMS [m] at the withheld fixes: the fused trajectory, linear interpolation, and the fused
    trajectory's own claim (rms of its horizontal sigma); counts of fixes."""

    fused_rms_m: float
    interpolation_rms_m: float
    claimed_rms_m: float
    withheld: int
    remaining: int
    rejected: int


def score_outages(log: KittiLog, time: np.ndarray, lat_deg: np.ndarray, lon_deg: np.ndarray, height: np.ndarray,
                  sigma_n: np.ndarray, sigma_e: np.ndarray, rejected: int) -> OutageScore:
    """Score a trajectory (IMU positions at ``time``; the KITTI GNSS lever arm is zero) on the protocol."""
    out = withheld(log.gnss_time)
    t = log.gnss_time[out]
    inside = (t >= time[0]) & (t <= time[-1])
    enu = geodetic_to_enu(lat_deg, lon_deg, height)
    est = np.stack([np.interp(t[inside], time, enu[:, k]) for k in range(2)], -1)
    err = est - log.gnss_enu[out][inside, :2]
    kept_t, kept = log.gnss_time[~out], log.gnss_enu[~out]
    lin = np.stack([np.interp(t, kept_t, kept[:, k]) for k in range(2)], -1) - log.gnss_enu[out, :2]
    claim = np.interp(t[inside], time, sigma_n) ** 2 + np.interp(t[inside], time, sigma_e) ** 2
    return OutageScore(fused_rms_m=float(np.sqrt(np.mean(np.sum(err**2, axis=1)))),
                       interpolation_rms_m=float(np.sqrt(np.mean(np.sum(lin**2, axis=1)))),
                       claimed_rms_m=float(np.sqrt(np.mean(claim))), withheld=int(out.sum()),
                       remaining=int((~out).sum()), rejected=int(rejected))
