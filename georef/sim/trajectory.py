"""Smooth, physically consistent flight trajectories: survey strips, coordinated turns, crab, climbs.

The trajectory is built from control profiles (air heading rate, vertical speed) on a fine time grid,
integrated in geodetic coordinates, and then differentiated into the exact inertial measurements an
ideal strapdown IMU would make under georef's Earth model (see ``docs/simulator.md``):

* ``v_n`` NED ground velocity = air velocity (heading ``psi_air``, airspeed) + constant wind;
* ``lat_dot = v_N/(M+h)``, ``lon_dot = v_E/((N+h) cos lat)``, ``h_dot = -v_D``;
* specific force ``f_n = dv_n/dt + (2 omega_ie_n + omega_en_n) x v_n - [0, 0, g(lat, h)]``;
* body rate ``omega_ib_b = omega_nb_b + C_n_b (omega_ie_n + omega_en_n)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.integrate import cumulative_trapezoid
from scipy.spatial.transform import Rotation

from georef.frames import (
    dcm_to_euler,
    earth_rate_n,
    euler_to_dcm,
    ned_to_lat_lon,
    normal_gravity,
    transport_rate_n,
    wrap_pi,
)


@dataclass
class FlightPlan:
    """A survey flight: parallel strips joined by coordinated 180-degree turns, with climbs.

    Units: seconds, metres, m/s, degrees (angles of the plan are degrees for readability).
    """

    duration_s: float = 180.0
    start_lat_deg: float = 44.047
    start_lon_deg: float = 15.62
    start_height_m: float = 760.0
    strip_heading_deg: float = 20.0
    airspeed_mps: float = 30.0
    strip_duration_s: float = 50.0
    turn_rate_deg_s: float = 6.0
    turn_ramp_s: float = 3.0
    wind_from_deg: float = 290.0
    wind_speed_mps: float = 2.1
    climb_rate_mps: float = 2.0
    climb_every_n_strips: int = 2
    climb_duration_s: float = 15.0
    trim_pitch_deg: float = 1.5
    turbulence_deg: float = 0.8
    seed: int = 0


@dataclass
class Trajectory:
    """Truth on a time grid: SI units, radians, NED velocity, body-to-NED Euler angles, ideal IMU."""

    time: np.ndarray          # (N,) s
    lat: np.ndarray           # (N,) rad
    lon: np.ndarray           # (N,) rad
    height: np.ndarray        # (N,) m
    v_n: np.ndarray           # (N, 3) m/s
    a_n: np.ndarray           # (N, 3) m/s^2, dv_n/dt
    roll: np.ndarray          # (N,) rad
    pitch: np.ndarray
    yaw: np.ndarray
    omega_ib_b: np.ndarray    # (N, 3) rad/s
    f_ib_b: np.ndarray        # (N, 3) m/s^2

    def subsample(self, index: np.ndarray | slice) -> Trajectory:
        return Trajectory(**{name: getattr(self, name)[index] for name in self.__dataclass_fields__})

    @property
    def C_b_n(self) -> np.ndarray:
        return euler_to_dcm(self.roll, self.pitch, self.yaw)


def _smooth_step(t: np.ndarray, start: float, ramp: float) -> np.ndarray:
    """0 before ``start``, 1 after ``start + ramp``, a raised-cosine in between (C1 continuous)."""
    x = np.clip((t - start) / ramp, 0.0, 1.0)
    return 0.5 - 0.5 * np.cos(np.pi * x)


def _pulse(t: np.ndarray, start: float, length: float, ramp: float) -> np.ndarray:
    """A flat-topped pulse of height 1 from ``start`` for ``length`` s, with raised-cosine edges."""
    return _smooth_step(t, start, ramp) - _smooth_step(t, start + length - ramp, ramp)


def control_profiles(plan: FlightPlan, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Air-heading rate [rad/s] and vertical (down) speed [m/s] of the flight plan at times ``t`` [s]."""
    turn_rate = np.radians(plan.turn_rate_deg_s)
    # A 180-degree turn with ramps lasts pi/rate + ramp (the ramps each lose ramp/2 of full-rate time).
    turn_length = np.pi / turn_rate + plan.turn_ramp_s
    heading_rate = np.zeros_like(t)
    v_down = np.zeros_like(t)
    start, k, direction = plan.strip_duration_s, 0, 1.0
    while start < t[-1]:
        heading_rate += direction * turn_rate * _pulse(t, start, turn_length, plan.turn_ramp_s)
        if plan.climb_every_n_strips and k % plan.climb_every_n_strips == 0:
            climb_start = start + turn_length + 0.25 * plan.strip_duration_s
            sign = -1.0 if (k // plan.climb_every_n_strips) % 2 == 0 else 1.0
            v_down += sign * plan.climb_rate_mps * _pulse(t, climb_start, plan.climb_duration_s, 4.0)
        start += turn_length + plan.strip_duration_s
        direction = -direction
        k += 1
    return heading_rate, v_down


def _turbulence(t: np.ndarray, amplitude_rad: float, rng: np.random.Generator) -> np.ndarray:
    """Smooth attitude perturbations [rad], (N, 3): sums of low-frequency sinusoids (0.05-0.5 Hz)."""
    out = np.zeros((len(t), 3))
    for axis in range(3):
        for _ in range(4):
            freq = rng.uniform(0.05, 0.5)
            out[:, axis] += amplitude_rad / 2.0 * np.sin(2 * np.pi * freq * t + rng.uniform(0, 2 * np.pi))
    return out


def integrate_position(t: np.ndarray, v_n: np.ndarray, lat0: float, lon0: float,
                       h0: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Geodetic position (lat, lon [rad], height [m]) from NED velocity [m/s] on times ``t`` [s].

    ``lat' = v_N/(M+h)``, ``lon' = v_E/((N+h) cos lat)``, ``h' = -v_D`` integrated by the trapezoid rule from
    ``(lat0, lon0 [rad], h0 [m])`` at ``t[0]``; the radii of curvature (``georef.frames``) are refined by
    fixed-point iteration (:func:`georef.frames.ned_to_lat_lon`). Second-order accurate in the grid step.
    """
    height = h0 - cumulative_trapezoid(v_n[:, 2], t, initial=0.0)
    lat = np.full_like(t, lat0)
    for _ in range(3):
        lat_rate, _ = ned_to_lat_lon(v_n[:, 0], v_n[:, 1], lat, height)
        lat = lat0 + cumulative_trapezoid(lat_rate, t, initial=0.0)
    _, lon_rate = ned_to_lat_lon(v_n[:, 0], v_n[:, 1], lat, height)
    lon = lon0 + cumulative_trapezoid(lon_rate, t, initial=0.0)
    return lat, lon, height


def _integrate_position(plan: FlightPlan, t: np.ndarray, v_n: np.ndarray) -> tuple[np.ndarray, ...]:
    """Integrate NED velocity into geodetic position from the plan's start point."""
    return integrate_position(t, v_n, np.radians(plan.start_lat_deg), np.radians(plan.start_lon_deg),
                              plan.start_height_m)


def _body_rate_nb(t: np.ndarray, C_b_n: np.ndarray) -> np.ndarray:
    """omega_nb_b [rad/s] from C_b_n(t) by central differences on SO(3) (second-order accurate)."""
    rot = Rotation.from_matrix(C_b_n)
    omega = np.empty((len(t), 3))
    omega[1:-1] = (rot[:-2].inv() * rot[2:]).as_rotvec() / (t[2:] - t[:-2])[:, None]
    omega[0] = (rot[0].inv() * rot[1]).as_rotvec() / (t[1] - t[0])
    omega[-1] = (rot[-2].inv() * rot[-1]).as_rotvec() / (t[-1] - t[-2])
    return omega


def specific_force_n(lat: np.ndarray, height: np.ndarray, v_n: np.ndarray, a_n: np.ndarray) -> np.ndarray:
    """Specific force in NED [m/s^2], (N, 3), that moves a body along the given kinematics.

    ``f_n = dv_n/dt + (2 omega_ie_n + omega_en_n) x v_n - [0, 0, g(lat, h)]`` with Earth rate, transport rate
    and normal gravity of ``georef.frames``. ``lat`` [rad], ``height`` [m], ``v_n`` NED velocity [m/s],
    ``a_n = dv_n/dt`` [m/s^2] (the derivative of the NED components, as the strapdown velocity equation uses).
    """
    g = normal_gravity(lat, height)
    omega_ie_n = earth_rate_n(lat)
    omega_en_n = transport_rate_n(lat, height, v_n)
    gravity_n = np.stack([np.zeros_like(g), np.zeros_like(g), g], axis=-1)
    return a_n + np.cross(2.0 * omega_ie_n + omega_en_n, v_n) - gravity_n


def imu_from_kinematics(t: np.ndarray, lat: np.ndarray, lon: np.ndarray, height: np.ndarray, v_n: np.ndarray,
                        a_n: np.ndarray, roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> Trajectory:
    """Any vehicle's truth -> the exactly consistent ideal IMU under georef's Earth model.

    Inputs on a fine time grid ``t`` [s] (>= 400 Hz recommended; rates come from central differences):
    geodetic position ``lat, lon`` [rad], ellipsoidal ``height`` [m], NED velocity ``v_n`` [m/s] (N, 3) and its
    time derivative ``a_n`` [m/s^2] (N, 3), ZYX Euler angles ``roll, pitch, yaw`` [rad] of body (x forward,
    y right, z down) to NED. Position must be the integral of ``v_n`` (see :func:`integrate_position`).

    Outputs, in the returned :class:`Trajectory`:

    * ``omega_ib_b = omega_nb_b + C_n_b (omega_ie_n + omega_en_n)`` [rad/s], ``omega_nb_b`` by central
      differences on SO(3);
    * ``f_ib_b = C_n_b f_n`` [m/s^2] with ``f_n`` of :func:`specific_force_n`;
    * Euler angles re-extracted from ``C_b_n`` (yaw wrapped to (-pi, pi]).
    """
    C_b_n = euler_to_dcm(roll, pitch, yaw)
    omega_ie_n = earth_rate_n(lat)
    omega_en_n = transport_rate_n(lat, height, v_n)
    C_n_b = np.swapaxes(C_b_n, -1, -2)
    omega_ib_b = _body_rate_nb(t, C_b_n) + np.einsum("nij,nj->ni", C_n_b, omega_ie_n + omega_en_n)
    f_n = specific_force_n(lat, height, v_n, a_n)
    f_ib_b = np.einsum("nij,nj->ni", C_n_b, f_n)
    roll, pitch, yaw = dcm_to_euler(C_b_n)
    return Trajectory(time=t, lat=lat, lon=lon, height=height, v_n=v_n, a_n=a_n, roll=roll, pitch=pitch,
                      yaw=yaw, omega_ib_b=omega_ib_b, f_ib_b=f_ib_b)


def fly(plan: FlightPlan, fine_rate_hz: float) -> Trajectory:
    """The helicopter survey's truth trajectory and ideal IMU on a grid of ``fine_rate_hz`` from t = 0 s."""
    rng = np.random.default_rng(plan.seed)
    n = int(round(plan.duration_s * fine_rate_hz)) + 1
    t = np.arange(n) / fine_rate_hz
    heading_rate, v_down = control_profiles(plan, t)
    psi_air = np.radians(plan.strip_heading_deg) + cumulative_trapezoid(heading_rate, t, initial=0.0)
    wind_to = np.radians(plan.wind_from_deg + 180.0)
    wind = plan.wind_speed_mps * np.array([np.cos(wind_to), np.sin(wind_to)])
    v_horizontal_air = np.sqrt(plan.airspeed_mps**2 - v_down**2)
    v_n = np.stack([v_horizontal_air * np.cos(psi_air) + wind[0],
                    v_horizontal_air * np.sin(psi_air) + wind[1], v_down], axis=-1)
    lat, lon, height = _integrate_position(plan, t, v_n)
    a_n = np.gradient(v_n, t, axis=0)

    g = normal_gravity(lat, height)
    perturbation = _turbulence(t, np.radians(plan.turbulence_deg), rng)
    roll = np.arctan(v_horizontal_air * heading_rate / g) + perturbation[:, 0]
    pitch = np.arctan2(-v_down, v_horizontal_air) + np.radians(plan.trim_pitch_deg) + perturbation[:, 1]
    yaw = wrap_pi(psi_air + 0.25 * perturbation[:, 2])
    return imu_from_kinematics(t, lat, lon, height, v_n, a_n, roll, pitch, yaw)
