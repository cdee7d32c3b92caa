"""A multicopter (drone) mapping flight: a hover, then legs flown sideways with the heading held.

The drone starts hovering ``hover_height_m`` above its start point with a small position-hold wander and
attitude wobble, then flies straight legs in the plan's track directions at 2-12 m/s. Velocity changes are
smootherstep transitions limited to ``max_accel_mps2`` (see :mod:`georef.sim.profiles`), so acceleration
and jerk are continuous. The heading follows ``heading_policy``:

* ``fixed``: yaw held at ``heading_deg`` (e.g. the camera pointing north) whatever the track, so a leg at
  track ``d`` is flown at ``d - heading`` sideways; during the optional second hover the heading turns by
  ``second_hover_yaw_turn_deg`` and is held at the new value afterwards;
* ``track``: yaw turns to each leg's track at the start of the leg (no sideways flight in the legs);
* ``rotating``: yaw rotates at ``rotate_rate_deg_s`` from the first leg on.

Climbs and descents between leg heights (50-120 m above the start point) use a vertical speed up to
``max_climb_mps`` reached and left with smootherstep transitions (vertical acceleration ``max_vertical_accel_mps2``).

Attitude: a multicopter's thrust acts along body -z, so body z points along minus the specific force
``f_n`` (:func:`georef.sim.trajectory.specific_force_n`: kinematic acceleration, Coriolis and transport
terms, normal gravity); roll and pitch follow from the required acceleration and gravity, yaw is commanded.
A small wobble (sums of 0.3-2 Hz sinusoids, amplitude ``wobble_deg`` in roll and in pitch) is added on top:
it stands for drag, gusts and the attitude controller's error, and bounds how far the specific force leaves
body z. Frames: body x forward, y right, z down; NED; angles of the plan in degrees, SI elsewhere.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.integrate import cumulative_trapezoid

from georef.frames import dcm_to_euler, wrap_pi
from georef.sim.profiles import SMOOTHERSTEP_PEAK_SLOPE, piecewise_smooth, sinusoids, transition_time
from georef.sim.trajectory import Trajectory, imu_from_kinematics, integrate_position, specific_force_n

HEADING_POLICIES = ("fixed", "track", "rotating")


@dataclass
class MulticopterPlan:
    """A multicopter flight. Units: s, m, m/s, m/s^2, deg, deg/s; heights above the start point."""

    duration_s: float = 120.0
    start_lat_deg: float = 44.047
    start_lon_deg: float = 15.62
    #: ellipsoidal height of the start (take-off) point [m]
    start_height_m: float = 150.0
    #: height of the first hover above the start point [m]
    hover_height_m: float = 60.0
    #: length of the hover at the start [s]
    hover_s: float = 15.0
    #: track direction of each leg, clockwise from north [deg]; legs repeat when the flight is longer
    leg_directions_deg: tuple[float, ...] = (90.0, 0.0, 270.0, 0.0, 135.0)
    #: height of each leg above the start point [m]
    leg_heights_m: tuple[float, ...] = (60.0, 80.0, 80.0, 100.0, 70.0)
    #: distance flown at constant velocity in each leg [m]
    leg_length_m: float = 120.0
    speed_mps: float = 8.0
    max_accel_mps2: float = 2.0
    max_climb_mps: float = 3.0
    max_vertical_accel_mps2: float = 1.0
    heading_policy: str = "fixed"
    #: initial heading; the held heading of the ``fixed`` policy [deg]
    heading_deg: float = 0.0
    #: peak yaw rate of heading turns [deg/s]
    max_yaw_rate_deg_s: float = 30.0
    #: yaw rate of the ``rotating`` policy [deg/s]
    rotate_rate_deg_s: float = 6.0
    #: a second hover after this leg (0-based; -1: none)
    second_hover_after_leg: int = 2
    second_hover_s: float = 8.0
    #: heading turn during the second hover (``fixed`` policy) [deg]
    second_hover_yaw_turn_deg: float = 90.0
    #: attitude wobble amplitude in roll and in pitch [deg] (sum of the 0.3-2 Hz components)
    wobble_deg: float = 0.8
    #: position-hold wander amplitude per horizontal axis [m] (half of it vertically), 0.03-0.12 Hz
    position_hold_m: float = 0.3
    seed: int = 0

    def __post_init__(self) -> None:
        if self.heading_policy not in HEADING_POLICIES:
            raise ValueError(f"heading_policy must be one of {', '.join(HEADING_POLICIES)}, "
                             f"got {self.heading_policy!r}")
        if not self.leg_directions_deg or len(self.leg_heights_m) != len(self.leg_directions_deg):
            raise ValueError("leg_directions_deg and leg_heights_m need the same, non-zero number of legs")
        if self.speed_mps <= 0 or self.max_accel_mps2 <= 0 or self.max_climb_mps <= 0:
            raise ValueError("speed, acceleration and climb limits must be positive")


@dataclass
class MulticopterSchedule:
    """When the plan does what (seconds from the start).

    ``legs``: (start, end, track [deg], heading [deg] or NaN when the heading is not held) of each leg's
    constant-velocity part; ``hovers``: (start, end) of every hover, the first from t = 0. The control
    transitions as (starts [s], durations [s], levels) for :func:`georef.sim.profiles.piecewise_smooth`:
    ``velocity`` horizontal NE velocity [m/s], ``vertical`` down velocity [m/s], ``yaw`` [rad, unwrapped];
    ``rotate_from_s``: when the ``rotating`` policy starts turning.
    """

    legs: list[tuple[float, float, float, float]] = field(default_factory=list)
    hovers: list[tuple[float, float]] = field(default_factory=list)
    velocity: tuple[list[float], list[float], list[np.ndarray]] = field(default_factory=lambda: ([], [], []))
    vertical: tuple[list[float], list[float], list[float]] = field(default_factory=lambda: ([], [], []))
    yaw: tuple[list[float], list[float], list[float]] = field(default_factory=lambda: ([], [], []))
    rotate_from_s: float | None = None


def add_transition(profile: tuple[list, list, list], start: float, duration: float, level: object) -> float:
    """Append a transition (start [s], duration [s], level) to a profile of
    :func:`georef.sim.profiles.piecewise_smooth`, starting no earlier than the previous one ends; returns its end
    [s]."""
    starts, durations, levels = profile
    if starts:
        start = max(start, starts[-1] + durations[-1])
    starts.append(start)
    durations.append(duration)
    levels.append(level)
    return start + duration


def add_climb(vertical: tuple[list, list, list], start: float, delta_h: float, max_climb_mps: float,
              max_accel_mps2: float) -> float:
    """Down-velocity transitions for a height change ``delta_h`` [m] (up positive), starting at ``start`` [s] or
    later: a climb speed of at most ``max_climb_mps`` [m/s] reached and left at ``max_accel_mps2`` [m/s^2] peak.
    Returns the end of the height change [s] (``start`` when there is none)."""
    if abs(delta_h) < 1e-9:
        return start
    a_v = max_accel_mps2
    v_c = min(max_climb_mps, np.sqrt(abs(delta_h) * a_v / SMOOTHERSTEP_PEAK_SLOPE))
    ramp = SMOOTHERSTEP_PEAK_SLOPE * v_c / a_v
    hold = (abs(delta_h) - v_c * ramp) / v_c  # each ramp covers v_c * ramp / 2
    v_down = -np.sign(delta_h) * v_c
    end = add_transition(vertical, start, ramp, v_down)
    return add_transition(vertical, end + max(hold, 0.0), ramp, 0.0)


def multicopter_schedule(plan: MulticopterPlan) -> MulticopterSchedule:
    """The plan's legs, hovers and control transitions (a short loop over legs, not over samples)."""
    sched = MulticopterSchedule()
    sched.hovers.append((0.0, plan.hover_s))
    t = plan.hover_s
    v_prev = np.zeros(2)
    h_prev = plan.hover_height_m
    yaw_prev = np.radians(plan.heading_deg)
    held = yaw_prev
    k = 0
    n_legs = len(plan.leg_directions_deg)
    while t < plan.duration_s:
        direction = np.radians(plan.leg_directions_deg[k % n_legs])
        v_target = plan.speed_mps * np.array([np.cos(direction), np.sin(direction)])
        end_v = add_transition(sched.velocity, t, transition_time(v_target - v_prev, plan.max_accel_mps2), v_target)
        end_yaw = end_v
        if plan.heading_policy == "track":
            turn = float(wrap_pi(direction - yaw_prev))
            if abs(turn) > 1e-9:
                end_yaw = add_transition(sched.yaw, t, transition_time(turn, np.radians(plan.max_yaw_rate_deg_s)),
                               yaw_prev + turn)
                yaw_prev += turn
        elif plan.heading_policy == "rotating" and sched.rotate_from_s is None:
            sched.rotate_from_s = t
        height = plan.leg_heights_m[k % n_legs]
        add_climb(sched.vertical, t, height - h_prev, plan.max_climb_mps, plan.max_vertical_accel_mps2)
        h_prev = height
        cruise_start = max(end_v, end_yaw)
        cruise_end = cruise_start + plan.leg_length_m / plan.speed_mps
        heading = {"fixed": np.degrees(held), "track": np.degrees(direction)}.get(plan.heading_policy, np.nan)
        sched.legs.append((cruise_start, cruise_end, float(np.degrees(direction)), float(heading)))
        t = cruise_end
        v_prev = v_target
        if k == plan.second_hover_after_leg:
            t = add_transition(sched.velocity, t, transition_time(v_prev, plan.max_accel_mps2), np.zeros(2))
            v_prev = np.zeros(2)
            length = plan.second_hover_s
            if plan.heading_policy == "fixed" and plan.second_hover_yaw_turn_deg:
                turn = np.radians(plan.second_hover_yaw_turn_deg)
                turn_time = transition_time(turn, np.radians(plan.max_yaw_rate_deg_s))
                add_transition(sched.yaw, t + 1.0, turn_time, held + turn)
                held += turn
                yaw_prev = held
                length = max(length, turn_time + 2.0)
            sched.hovers.append((t, t + length))
            t += length
        k += 1
    return sched


def fly_multicopter(plan: MulticopterPlan, fine_rate_hz: float) -> Trajectory:
    """The multicopter's truth and ideal IMU on a grid of ``fine_rate_hz`` [Hz] from t = 0 s.

    Kinematics from the schedule's smootherstep profiles plus the position-hold wander (analytic velocity
    and acceleration); position by :func:`georef.sim.trajectory.integrate_position`; thrust-aligned
    attitude with the commanded yaw plus wobble; IMU by :func:`georef.sim.trajectory.imu_from_kinematics`.
    """
    rng = np.random.default_rng(plan.seed)
    n = int(round(plan.duration_s * fine_rate_hz)) + 1
    t = np.arange(n) / fine_rate_hz
    sched = multicopter_schedule(plan)

    v_h, a_h, _ = piecewise_smooth(t, np.zeros(2), *profile_arrays(sched.velocity, (0, 2)))
    v_d, a_d, _ = piecewise_smooth(t, 0.0, *profile_arrays(sched.vertical, (0,)))
    v_n = np.column_stack([v_h, v_d])
    a_n = np.column_stack([a_h, a_d])
    # position-hold wander: two low-frequency components per axis (N, E, D; D at half the amplitude)
    for axis, scale in enumerate((1.0, 1.0, 0.5)):
        amplitude = np.full(2, 0.5 * scale * plan.position_hold_m)
        _, dv, da = sinusoids(t, amplitude, rng.uniform(0.03, 0.12, 2), rng.uniform(0, 2 * np.pi, 2))
        v_n[:, axis] += dv
        a_n[:, axis] += da
    lat, lon, height = integrate_position(t, v_n, np.radians(plan.start_lat_deg), np.radians(plan.start_lon_deg),
                                          plan.start_height_m + plan.hover_height_m)

    yaw, _, _ = piecewise_smooth(t, np.radians(plan.heading_deg), *profile_arrays(sched.yaw, (0,)))
    if sched.rotate_from_s is not None:
        ramp, _, _ = piecewise_smooth(t, 0.0, [sched.rotate_from_s], [2.0], [np.radians(plan.rotate_rate_deg_s)])
        yaw = yaw + cumulative_trapezoid(ramp, t, initial=0.0)
    roll, pitch, yaw = thrust_attitude(specific_force_n(lat, height, v_n, a_n), yaw)
    wobble = np.radians(plan.wobble_deg) / 3.0
    for angle in (roll, pitch):
        value, _, _ = sinusoids(t, np.full(3, wobble), rng.uniform(0.3, 2.0, 3), rng.uniform(0, 2 * np.pi, 3))
        angle += value
    return imu_from_kinematics(t, lat, lon, height, v_n, a_n, roll, pitch, yaw)


def profile_arrays(profile: tuple[list, list, list], level_shape: tuple[int, ...]) -> tuple[np.ndarray, ...]:
    """A profile's (starts, durations, levels) as arrays for :func:`georef.sim.profiles.piecewise_smooth`;
    ``level_shape`` is the shape of the empty levels array of a profile without transitions."""
    starts, durations, levels = profile
    if not starts:
        return np.empty(0), np.empty(0), np.empty(level_shape)
    return np.asarray(starts, float), np.asarray(durations, float), np.asarray(levels, float)


def thrust_attitude(f_n: np.ndarray, yaw: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Roll, pitch, yaw [rad] of a body whose z axis points along ``-f_n`` and whose ZYX yaw is ``yaw``.

    ``f_n`` (N, 3) NED specific force [m/s^2] (thrust per unit mass for a multicopter), ``yaw`` (N,) [rad].
    Body z = -f/|f|; body x is perpendicular to z and to the horizontal normal of the heading plane
    ``[-sin yaw, cos yaw, 0]`` (so the ZYX yaw of the result is ``yaw``); y = z x x. Angles from
    ``georef.frames.dcm_to_euler``.
    """
    z_b = -f_n / np.linalg.norm(f_n, axis=1, keepdims=True)
    normal = np.column_stack([-np.sin(yaw), np.cos(yaw), np.zeros_like(yaw)])
    x_b = np.cross(normal, z_b)
    x_b /= np.linalg.norm(x_b, axis=1, keepdims=True)
    y_b = np.cross(z_b, x_b)
    return dcm_to_euler(np.stack([x_b, y_b, z_b], axis=-1))
