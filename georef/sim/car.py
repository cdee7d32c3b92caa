"""A car on roads: blocks at cruising speed, turns at junctions, stops at lights, grades and banks.

The speed profile holds levels between 0 and 15 m/s and moves between them with smootherstep transitions
limited to ``accel_mps2`` / ``decel_mps2`` (:mod:`georef.sim.profiles`): a standstill at the start
(optional), blocks of ``block_length_m`` at ``cruise_speed_mps``, a slow-down to ``turn_speed_mps`` before
every junction where the heading turns by the next of ``turns_deg`` (peak yaw rate ``max_yaw_rate_deg_s``),
and a full stop of ``stop_s`` (a traffic light) before every ``stop_every_n_junctions``-th junction.

Attitude (body x forward, y right, z down; ZYX Euler angles to NED):

* yaw = heading = track: the car has no sideslip;
* pitch = road grade ``gamma(s)`` (sinusoids in arc length ``s``, amplitude ``grade_deg``) plus squat/dive of
  ``pitch_per_g_deg`` per g of longitudinal acceleration;
* roll = road bank (sinusoid in ``s``, amplitude ``bank_deg``) minus a lean of ``roll_per_g_deg`` per g of
  lateral acceleration ``v psi'`` (the body rolls to the outside of the turn).

Velocity ``v_n = v [cos gamma cos psi, cos gamma sin psi, -sin gamma]`` and its exact derivative; at a
standstill the velocity is exactly zero and the attitude constant. Units: s, m, m/s, m/s^2, deg in the plan.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.integrate import cumulative_trapezoid

from georef.frames import normal_gravity
from georef.sim.profiles import piecewise_smooth, transition_time
from georef.sim.trajectory import Trajectory, imu_from_kinematics, integrate_position


@dataclass
class CarPlan:
    """A drive. Units: s, m, m/s, m/s^2, deg, deg/s."""

    duration_s: float = 120.0
    start_lat_deg: float = 44.047
    start_lon_deg: float = 15.62
    #: ellipsoidal height of the start [m]
    start_height_m: float = 150.0
    start_heading_deg: float = 20.0
    #: standstill at the start [s]; 0 starts at cruising speed
    start_standstill_s: float = 8.0
    cruise_speed_mps: float = 12.0
    turn_speed_mps: float = 5.0
    accel_mps2: float = 1.5
    decel_mps2: float = 2.5
    #: distance at cruising speed between junctions [m]
    block_length_m: float = 150.0
    #: heading change at successive junctions, positive to the right [deg]; repeats
    turns_deg: tuple[float, ...] = (90.0, -90.0, 90.0, 45.0, -90.0, -45.0)
    max_yaw_rate_deg_s: float = 20.0
    #: stop at a light before every n-th junction (0: never) [-], for ``stop_s`` [s]
    stop_every_n_junctions: int = 2
    stop_s: float = 6.0
    #: road grade amplitude [deg] and wavelength along the road [m]
    grade_deg: float = 2.0
    grade_wavelength_m: float = 400.0
    #: road bank (cross slope) amplitude [deg] and wavelength [m]
    bank_deg: float = 1.0
    bank_wavelength_m: float = 250.0
    #: body lean [deg per g of lateral acceleration] and squat/dive [deg per g of longitudinal acceleration]
    roll_per_g_deg: float = 4.0
    pitch_per_g_deg: float = 2.0
    seed: int = 0

    def __post_init__(self) -> None:
        if not 0.0 < self.turn_speed_mps <= self.cruise_speed_mps <= 40.0:
            raise ValueError("need 0 < turn_speed_mps <= cruise_speed_mps <= 40 m/s")
        if self.accel_mps2 <= 0 or self.decel_mps2 <= 0 or self.max_yaw_rate_deg_s <= 0:
            raise ValueError("acceleration, deceleration and yaw-rate limits must be positive")
        if not self.turns_deg:
            raise ValueError("turns_deg needs at least one junction turn")


@dataclass
class CarSchedule:
    """Speed and heading transitions (start [s], duration [s], level [m/s] or [rad]) and the standstills.

    ``standstills``: (start, end) [s] of every interval at exactly zero speed; ``turns``: (start, end) of
    the heading changes.
    """

    speed: tuple[list[float], list[float], list[float]] = field(default_factory=lambda: ([], [], []))
    heading: tuple[list[float], list[float], list[float]] = field(default_factory=lambda: ([], [], []))
    standstills: list[tuple[float, float]] = field(default_factory=list)
    turns: list[tuple[float, float]] = field(default_factory=list)
    initial_speed: float = 0.0


def car_schedule(plan: CarPlan) -> CarSchedule:
    """The plan's speed and heading changes (a short loop over junctions, not over samples)."""
    sched = CarSchedule()
    speed_now = 0.0 if plan.start_standstill_s > 0 else plan.cruise_speed_mps
    sched.initial_speed = speed_now
    heading = np.radians(plan.start_heading_deg)
    t = 0.0

    def change_speed(level: float) -> None:
        nonlocal t, speed_now
        limit = plan.accel_mps2 if level > speed_now else plan.decel_mps2
        duration = transition_time(level - speed_now, limit)
        sched.speed[0].append(t)
        sched.speed[1].append(duration)
        sched.speed[2].append(level)
        t += duration
        speed_now = level

    if plan.start_standstill_s > 0:
        sched.standstills.append((0.0, plan.start_standstill_s))
        t = plan.start_standstill_s
        change_speed(plan.cruise_speed_mps)
    j = 0
    while t < plan.duration_s:
        t += plan.block_length_m / plan.cruise_speed_mps
        if plan.stop_every_n_junctions and (j + 1) % plan.stop_every_n_junctions == 0:
            change_speed(0.0)
            sched.standstills.append((t, t + plan.stop_s))
            t += plan.stop_s
        change_speed(plan.turn_speed_mps)
        turn = np.radians(plan.turns_deg[j % len(plan.turns_deg)])
        duration = transition_time(turn, np.radians(plan.max_yaw_rate_deg_s), minimum=2.0)
        heading += turn
        sched.heading[0].append(t)
        sched.heading[1].append(duration)
        sched.heading[2].append(heading)
        sched.turns.append((t, t + duration))
        t += duration
        change_speed(plan.cruise_speed_mps)
        j += 1
    return sched


def drive(plan: CarPlan, fine_rate_hz: float) -> Trajectory:
    """The car's truth and ideal IMU on a grid of ``fine_rate_hz`` [Hz] from t = 0 s (see the module doc)."""
    rng = np.random.default_rng(plan.seed)
    n = int(round(plan.duration_s * fine_rate_hz)) + 1
    t = np.arange(n) / fine_rate_hz
    sched = car_schedule(plan)
    speed, speed_dot, _ = piecewise_smooth(t, sched.initial_speed, *map(np.asarray, sched.speed))
    psi, psi_dot, _ = piecewise_smooth(t, np.radians(plan.start_heading_deg), *map(np.asarray, sched.heading))
    s = cumulative_trapezoid(speed, t, initial=0.0)

    k_grade = 2.0 * np.pi / plan.grade_wavelength_m
    k_bank = 2.0 * np.pi / plan.bank_wavelength_m
    phase_grade, phase_bank = rng.uniform(0, 2 * np.pi, 2)
    gamma = np.radians(plan.grade_deg) * np.sin(k_grade * s + phase_grade)
    gamma_dot = np.radians(plan.grade_deg) * k_grade * np.cos(k_grade * s + phase_grade) * speed
    bank = np.radians(plan.bank_deg) * np.sin(k_bank * s + phase_bank)

    cg, sg, cp, sp = np.cos(gamma), np.sin(gamma), np.cos(psi), np.sin(psi)
    direction = np.column_stack([cg * cp, cg * sp, -sg])
    v_n = speed[:, None] * direction
    a_n = (speed_dot[:, None] * direction
           + (speed * psi_dot)[:, None] * np.column_stack([-cg * sp, cg * cp, np.zeros_like(t)])
           + (speed * gamma_dot)[:, None] * np.column_stack([-sg * cp, -sg * sp, -cg]))
    lat, lon, height = integrate_position(t, v_n, np.radians(plan.start_lat_deg), np.radians(plan.start_lon_deg),
                                          plan.start_height_m)
    g = normal_gravity(lat, height)
    roll = bank - np.radians(plan.roll_per_g_deg) * speed * psi_dot / g
    pitch = gamma + np.radians(plan.pitch_per_g_deg) * speed_dot / g
    return imu_from_kinematics(t, lat, lon, height, v_n, a_n, roll, pitch, psi)
