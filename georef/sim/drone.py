"""A drone's whole log: still on the ground, rotor spin-up, take-off with its lift-off jolt, hover, survey, landing.

A real multicopter log starts at power-on with the drone standing on the ground; the simulator's
:class:`~georef.sim.multicopter.MulticopterPlan` starts it hovering. :class:`DronePlan` adds what comes before
and after the survey (times from the log start, ``start="ground"``):

1. **ground** ``[0, ground_s)``: motors off, the drone still on its landing gear, tilted by ``takeoff_tilt_deg``
   (uneven ground): velocity exactly zero, attitude exactly constant, so the ideal IMU sees gravity and Earth rate;
2. **spin-up** ``spinup_s``: the motors start and reach idle (``idle_thrust`` of the hover thrust), then idle for
   ``idle_s`` and throttle up to hover thrust in ``throttle_up_s``, all still on the ground;
3. **lift-off and take-off**: a vertical climb to ``survey.hover_height_m`` (``takeoff_climb_mps``, vertical
   acceleration ``takeoff_accel_mps2``) plus the lift-off jolt: the landing gear's spring and the ground contact
   throw the drone up with an extra upward velocity ``dv`` gained in ``liftoff_pulse_s`` (a smootherstep, peak
   acceleration ``liftoff_peak_mps2 - g``, so the specific force along body z peaks at ``liftoff_peak_mps2``,
   2-4.5 g on real logs) and taken back by the controller over ``liftoff_settle_s``; the climb is shortened by
   the jolt's extra rise so the hover height is met. The attitude goes from the ground tilt to the thrust
   attitude in 0.3 s, with a decaying tilt oscillation (``liftoff_wobble_deg`` at ``liftoff_wobble_hz``,
   time constant ``liftoff_wobble_decay_s``);
4. **hover** ``survey.hover_s`` at the hover height, then the survey's legs (:func:`multicopter_schedule`, every
   field of ``survey`` keeps its meaning; its ``duration_s`` is the length of the whole log, its start point is
   the take-off point);
5. **landing** (``land``): after the last leg the drone stops, descends vertically at ``landing_descent_mps``
   to the take-off height, settles on ``landing_tilt_deg``, the motors go to idle and stop in ``spindown_s``,
   and the log runs on for at least ``after_landing_s`` (legs are dropped from the end until it fits).

``start="hover"`` starts the log in the hover instead (the drone already airborne, motors at hover thrust), as
:class:`MulticopterPlan` does. The position-hold wander and the attitude wobble of the survey act only in the
air: they ramp in over 3 s after lift-off and out over the 3 s before touchdown (as a position, so the drone
leaves and meets the ground at its own spot).

The motors' **thrust ratio** (thrust / hover thrust, which sets the rotor speed ``~ sqrt(thrust)``) is the
ground profile above while on the ground and ``|f| / g`` in the air (specific force without the lift-off jolt,
which the landing gear gives, not the rotors). Frames: body x forward, y right, z down; NED; SI units inside,
degrees in the plan.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
from scipy.integrate import cumulative_trapezoid

from georef.frames import STANDARD_GRAVITY, normal_gravity
from georef.sim.multicopter import (
    MulticopterPlan,
    MulticopterSchedule,
    add_climb,
    add_transition,
    multicopter_schedule,
    profile_arrays,
    thrust_attitude,
)
from georef.sim.profiles import SMOOTHERSTEP_PEAK_SLOPE, piecewise_smooth, sinusoids, smootherstep, transition_time
from georef.sim.trajectory import Trajectory, imu_from_kinematics, integrate_position, specific_force_n

START_MODES = ("ground", "hover")
#: [s] the attitude moves between the ground tilt and the thrust attitude at lift-off and touchdown
AIR_BLEND_S = 0.3
#: [s] the position-hold wander and the wobble ramp in after lift-off and out before touchdown
AIR_ENVELOPE_S = 3.0
#: [s] onset of the lift-off tilt oscillation
LIFTOFF_ONSET_S = 0.1
#: [s] after touchdown: thrust down to idle in the first, idle held for the second, then the spin-down
TOUCHDOWN_IDLE_S = (1.0, 1.0)
#: [s] legs are dropped from the end in steps of this until a landing fits into the log
_LANDING_SEARCH_STEP_S = 5.0


@dataclass
class DronePlan:
    """A drone's log from power-on (or from a hover) to the end. Units: s, m, m/s, m/s^2, deg, Hz.

    ``survey`` holds the survey part (legs, heading policy, hover height and length, start point, wander,
    wobble, seed); ``survey.duration_s`` is the length of the whole log. Tilts are (roll, pitch) [deg].
    """

    survey: MulticopterPlan = field(default_factory=lambda: MulticopterPlan(duration_s=300.0, hover_s=8.0))
    start: str = "ground"
    ground_s: float = 20.0
    spinup_s: float = 2.5
    idle_s: float = 2.0
    throttle_up_s: float = 0.8
    #: idle thrust / hover thrust [-]
    idle_thrust: float = 0.15
    takeoff_tilt_deg: tuple[float, float] = (1.2, -1.8)
    landing_tilt_deg: tuple[float, float] = (-0.6, 0.9)
    takeoff_climb_mps: float = 2.5
    takeoff_accel_mps2: float = 1.5
    #: peak specific force along body -z at lift-off [m/s^2] (35 m/s^2 = 3.6 g)
    liftoff_peak_mps2: float = 35.0
    liftoff_pulse_s: float = 0.05
    liftoff_settle_s: float = 0.6
    liftoff_wobble_deg: float = 2.0
    liftoff_wobble_hz: float = 3.0
    liftoff_wobble_decay_s: float = 0.4
    land: bool = False
    landing_descent_mps: float = 1.5
    spindown_s: float = 2.0
    after_landing_s: float = 8.0

    def __post_init__(self) -> None:
        if self.start not in START_MODES:
            raise ValueError(f"start must be one of {', '.join(START_MODES)}, got {self.start!r}")
        durations = {"ground_s": self.ground_s, "spinup_s": self.spinup_s, "throttle_up_s": self.throttle_up_s,
                     "liftoff_pulse_s": self.liftoff_pulse_s, "liftoff_settle_s": self.liftoff_settle_s,
                     "spindown_s": self.spindown_s, "takeoff_climb_mps": self.takeoff_climb_mps,
                     "takeoff_accel_mps2": self.takeoff_accel_mps2, "landing_descent_mps": self.landing_descent_mps,
                     "liftoff_wobble_decay_s": self.liftoff_wobble_decay_s}
        bad = [name for name, value in durations.items() if not value > 0]
        if bad or self.idle_s < 0 or self.after_landing_s < 0:
            raise ValueError(f"drone plan: {', '.join(bad) or 'idle_s / after_landing_s'} must be positive")
        if not 0.0 < self.idle_thrust < 1.0:
            raise ValueError(f"idle_thrust is a fraction of the hover thrust in (0, 1), got {self.idle_thrust}")
        if self.liftoff_peak_mps2 < STANDARD_GRAVITY + 0.5:
            raise ValueError(f"liftoff_peak_mps2 is the peak specific force, at least g + 0.5 m/s^2, got "
                             f"{self.liftoff_peak_mps2}")

    @property
    def duration_s(self) -> float:
        """Length of the whole log [s] (``survey.duration_s``)."""
        return self.survey.duration_s

    @property
    def seed(self) -> int:
        return self.survey.seed


@dataclass
class DroneSchedule:
    """When the drone does what, in seconds from the log start.

    ``survey``: the legs, hovers and control transitions (:class:`MulticopterSchedule`, absolute times; its
    ``vertical`` profile also holds the take-off climb and the landing descent). ``thrust``: the thrust-ratio
    transitions on the ground (start, duration, level). ``motors_on_s`` / ``liftoff_s`` / ``touchdown_s`` /
    ``motors_off_s`` are None when the log has no such event (a hover start has no spin-up and no lift-off).
    ``hover_start_s``: the hover height is reached. ``hop_dv_mps``: the lift-off jolt's extra climb speed.
    """

    survey: MulticopterSchedule
    thrust: tuple[list[float], list[float], list[float]]
    hover_start_s: float
    motors_on_s: float | None = None
    liftoff_s: float | None = None
    touchdown_s: float | None = None
    motors_off_s: float | None = None
    hop_dv_mps: float = 0.0

    def on_ground(self, t: np.ndarray) -> np.ndarray:
        """True where the drone stands still on the ground (after touchdown: once it has settled)."""
        before = t < self.liftoff_s if self.liftoff_s is not None else np.zeros(len(t), bool)
        after = t >= self.touchdown_s + AIR_BLEND_S if self.touchdown_s is not None else np.zeros(len(t), bool)
        return before | after

    def motors_off(self, t: np.ndarray) -> np.ndarray:
        """True where the motors are stopped (before spin-up, after spin-down)."""
        before = t < self.motors_on_s if self.motors_on_s is not None else np.zeros(len(t), bool)
        after = t >= self.motors_off_s if self.motors_off_s is not None else np.zeros(len(t), bool)
        return before | after


@dataclass
class DroneTruth:
    """The drone's truth and ideal IMU on the fine grid, the motors' thrust ratio there and the schedule."""

    trajectory: Trajectory
    thrust_ratio: np.ndarray   # (N,) thrust / hover thrust [-], 0 with the motors off
    schedule: DroneSchedule


def drone_schedule(plan: DronePlan) -> DroneSchedule:
    """The plan's phases and control transitions (a short loop over legs, not over samples)."""
    thrust: tuple[list, list, list] = ([], [], [])
    takeoff: tuple[list, list, list] = ([], [], [])
    motors_on = liftoff = None
    hop_dv = 0.0
    hover_start = 0.0
    if plan.start == "ground":
        motors_on = plan.ground_s
        throttle = add_transition(thrust, motors_on, plan.spinup_s, plan.idle_thrust) + plan.idle_s
        liftoff = add_transition(thrust, throttle, plan.throttle_up_s, 1.0)
        hop_dv = (plan.liftoff_peak_mps2 - STANDARD_GRAVITY) * plan.liftoff_pulse_s / SMOOTHERSTEP_PEAK_SLOPE
        hop_rise = hop_dv * (plan.liftoff_pulse_s + plan.liftoff_settle_s) / 2.0  # each smootherstep: half
        if plan.survey.hover_height_m < hop_rise + 1.0:
            raise ValueError(f"hover height {plan.survey.hover_height_m} m: the drone needs at least "
                             f"{hop_rise + 1.0:.2f} m to climb after its lift-off jolt")
        climbed = add_climb(takeoff, liftoff, plan.survey.hover_height_m - hop_rise, plan.takeoff_climb_mps,
                            plan.takeoff_accel_mps2)
        hover_start = max(climbed, liftoff + plan.liftoff_pulse_s + plan.liftoff_settle_s)
    legs_until = plan.duration_s
    while True:
        survey = multicopter_schedule(dataclasses.replace(
            plan.survey, hover_s=hover_start + plan.survey.hover_s, duration_s=legs_until))
        survey.hovers[0] = (hover_start, hover_start + plan.survey.hover_s)
        survey.vertical = (takeoff[0] + survey.vertical[0], takeoff[1] + survey.vertical[1],
                           takeoff[2] + survey.vertical[2])
        sched = DroneSchedule(survey=survey, thrust=(list(thrust[0]), list(thrust[1]), list(thrust[2])),
                              hover_start_s=hover_start, motors_on_s=motors_on, liftoff_s=liftoff, hop_dv_mps=hop_dv)
        if not plan.land:
            return sched
        _add_landing(sched, plan)
        assert sched.motors_off_s is not None
        if sched.motors_off_s + plan.after_landing_s <= plan.duration_s:
            return sched
        legs_until -= _LANDING_SEARCH_STEP_S
        if legs_until <= hover_start + plan.survey.hover_s:
            raise ValueError(f"a {plan.duration_s:g} s log is too short for the take-off, one leg and a landing")


def _add_landing(sched: DroneSchedule, plan: DronePlan) -> None:
    """Stop after the last leg (or hover), descend to the take-off height, touch down, spin down."""
    survey = sched.survey
    t = max(survey.legs[-1][1], survey.hovers[-1][1]) if survey.legs else survey.hovers[-1][1]
    velocity_levels = survey.velocity[2]
    if velocity_levels and np.linalg.norm(velocity_levels[-1]) > 0:
        t = add_transition(survey.velocity, t, transition_time(velocity_levels[-1], plan.survey.max_accel_mps2),
                           np.zeros(2))
    n_legs = len(plan.survey.leg_directions_deg)
    height = plan.survey.leg_heights_m[(len(survey.legs) - 1) % n_legs] if survey.legs else \
        plan.survey.hover_height_m
    touchdown = add_climb(survey.vertical, t, -height, plan.landing_descent_mps, plan.survey.max_vertical_accel_mps2)
    to_idle, idle = TOUCHDOWN_IDLE_S
    add_transition(sched.thrust, touchdown, to_idle, plan.idle_thrust)
    sched.touchdown_s = touchdown
    sched.motors_off_s = add_transition(sched.thrust, touchdown + to_idle + idle, plan.spindown_s, 0.0)


def fly_drone(plan: DronePlan, fine_rate_hz: float) -> DroneTruth:
    """The drone's truth, ideal IMU and thrust ratio on a grid of ``fine_rate_hz`` [Hz] from t = 0 s.

    Kinematics from smootherstep profiles (velocity, climbs, the lift-off jolt) plus the position-hold wander
    gated by the airborne envelope; position by :func:`integrate_position`; attitude: the ground tilt on the
    ground, the thrust attitude (body z along minus the specific force, commanded yaw) plus wobble in the air;
    IMU by :func:`imu_from_kinematics`.
    """
    rng = np.random.default_rng(plan.seed)
    n = int(round(plan.duration_s * fine_rate_hz)) + 1
    t = np.arange(n) / fine_rate_hz
    sched = drone_schedule(plan)
    survey = sched.survey

    v_h, a_h, _ = piecewise_smooth(t, np.zeros(2), *profile_arrays(survey.velocity, (0, 2)))
    v_d, a_d, _ = piecewise_smooth(t, 0.0, *profile_arrays(survey.vertical, (0,)))
    hop_v, hop_a = _hop(t, plan, sched)
    v_n = np.column_stack([v_h, v_d - hop_v])
    a_n = np.column_stack([a_h, a_d - hop_a])
    air, air_rate, air_accel = _airborne_envelope(t, sched)
    # position-hold wander as a position gated by the envelope: zero displacement on the ground
    for axis, scale in enumerate((1.0, 1.0, 0.5)):
        amplitude = np.full(2, 0.5 * scale * plan.survey.position_hold_m)
        p, dp, ddp = sinusoids(t, amplitude, rng.uniform(0.03, 0.12, 2), rng.uniform(0, 2 * np.pi, 2))
        v_n[:, axis] += air_rate * p + air * dp
        a_n[:, axis] += air_accel * p + 2.0 * air_rate * dp + air * ddp
    # height = take-off height + hover height - wander (down): a hover start begins at its wander's offset, so
    # that a landing meets the take-off height
    h0 = plan.survey.start_height_m
    if plan.start == "hover":
        h0 += plan.survey.hover_height_m - air[0] * p[0]
    lat, lon, height = integrate_position(t, v_n, np.radians(plan.survey.start_lat_deg),
                                          np.radians(plan.survey.start_lon_deg), h0)

    yaw = _commanded_yaw(t, plan, survey)
    roll_air, pitch_air, yaw = thrust_attitude(specific_force_n(lat, height, v_n, a_n), yaw)
    blend, _, _ = piecewise_smooth(t, 0.0 if plan.start == "ground" else 1.0, *_blend_transitions(sched))
    ground_roll, ground_pitch = _ground_tilt(t, plan, sched)
    wobble = np.radians(plan.survey.wobble_deg) / 3.0
    wobbles = [sinusoids(t, np.full(3, wobble), rng.uniform(0.3, 2.0, 3), rng.uniform(0, 2 * np.pi, 3))[0]
               for _ in range(2)]
    jolt_roll, jolt_pitch = _liftoff_oscillation(t, plan, sched, rng)
    roll = blend * roll_air + (1.0 - blend) * ground_roll + air * wobbles[0] + jolt_roll
    pitch = blend * pitch_air + (1.0 - blend) * ground_pitch + air * wobbles[1] + jolt_pitch
    trajectory = imu_from_kinematics(t, lat, lon, height, v_n, a_n, roll, pitch, yaw)

    a_rotors = a_n.copy()
    a_rotors[:, 2] += hop_a  # the jolt is the landing gear's push, not thrust
    airborne_thrust = np.linalg.norm(specific_force_n(lat, height, v_n, a_rotors), axis=1) / \
        normal_gravity(lat, height)
    ground_thrust, _, _ = piecewise_smooth(t, 0.0 if plan.start == "ground" else 1.0,
                                           *profile_arrays(sched.thrust, (0,)))
    in_air = ~sched.on_ground(t)
    if sched.touchdown_s is not None:
        in_air &= t < sched.touchdown_s
    return DroneTruth(trajectory=trajectory, thrust_ratio=np.where(in_air, airborne_thrust, ground_thrust),
                      schedule=sched)


def _hop(t: np.ndarray, plan: DronePlan, sched: DroneSchedule) -> tuple[np.ndarray, np.ndarray]:
    """The lift-off jolt: extra upward velocity [m/s] and its acceleration [m/s^2] (zero for a hover start)."""
    if sched.liftoff_s is None:
        return np.zeros_like(t), np.zeros_like(t)
    end_pulse = sched.liftoff_s + plan.liftoff_pulse_s
    up, rate, _ = piecewise_smooth(t, 0.0, [sched.liftoff_s, end_pulse], [plan.liftoff_pulse_s, plan.liftoff_settle_s],
                                   [sched.hop_dv_mps, 0.0])
    return up, rate


def _airborne_envelope(t: np.ndarray, sched: DroneSchedule) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """0 on the ground, 1 in the air (value, rate, acceleration): ramps after lift-off and before touchdown."""
    starts, durations, levels = [], [], []
    if sched.liftoff_s is not None:
        starts.append(sched.liftoff_s)
        durations.append(AIR_ENVELOPE_S)
        levels.append(1.0)
    if sched.touchdown_s is not None:
        starts.append(sched.touchdown_s - AIR_ENVELOPE_S)
        durations.append(AIR_ENVELOPE_S)
        levels.append(0.0)
    return piecewise_smooth(t, 0.0 if sched.liftoff_s is not None else 1.0, starts, durations, levels)


def _blend_transitions(sched: DroneSchedule) -> tuple[list[float], list[float], list[float]]:
    """Transitions of the ground-tilt -> thrust-attitude blend: up at lift-off, down at touchdown."""
    starts, levels = [], []
    if sched.liftoff_s is not None:
        starts.append(sched.liftoff_s)
        levels.append(1.0)
    if sched.touchdown_s is not None:
        starts.append(sched.touchdown_s)
        levels.append(0.0)
    return starts, [AIR_BLEND_S] * len(starts), levels


def _ground_tilt(t: np.ndarray, plan: DronePlan, sched: DroneSchedule) -> tuple[np.ndarray, np.ndarray]:
    """Roll and pitch [rad] of the drone on the ground: the take-off spot's, then the landing spot's."""
    landed = t >= sched.touchdown_s if sched.touchdown_s is not None else np.zeros(len(t), bool)
    roll = np.where(landed, np.radians(plan.landing_tilt_deg[0]), np.radians(plan.takeoff_tilt_deg[0]))
    pitch = np.where(landed, np.radians(plan.landing_tilt_deg[1]), np.radians(plan.takeoff_tilt_deg[1]))
    return roll, pitch


def _commanded_yaw(t: np.ndarray, plan: DronePlan, survey: MulticopterSchedule) -> np.ndarray:
    """Yaw [rad, unwrapped] of the heading policy (as :func:`georef.sim.multicopter.fly_multicopter`)."""
    yaw, _, _ = piecewise_smooth(t, np.radians(plan.survey.heading_deg), *profile_arrays(survey.yaw, (0,)))
    if survey.rotate_from_s is not None:
        ramp, _, _ = piecewise_smooth(t, 0.0, [survey.rotate_from_s], [2.0],
                                      [np.radians(plan.survey.rotate_rate_deg_s)])
        yaw = yaw + cumulative_trapezoid(ramp, t, initial=0.0)
    return yaw


def _liftoff_oscillation(t: np.ndarray, plan: DronePlan, sched: DroneSchedule,
                         rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Decaying roll and pitch oscillation [rad] after lift-off (zero before it, and for a hover start).

    Amplitude ``liftoff_wobble_deg`` times a random 0.5-1 per axis, onset over 0.1 s, decay
    ``exp(-dt / liftoff_wobble_decay_s)``. The draws are made for a hover start too, so both starts draw alike.
    """
    scale = rng.uniform(0.5, 1.0, 2)
    phase = rng.uniform(0, 2 * np.pi, 2)
    if sched.liftoff_s is None:
        return np.zeros_like(t), np.zeros_like(t)
    dt = np.maximum(t - sched.liftoff_s, 0.0)
    onset, _, _ = smootherstep(dt / LIFTOFF_ONSET_S)
    envelope = np.radians(plan.liftoff_wobble_deg) * onset * np.exp(-dt / plan.liftoff_wobble_decay_s)
    return tuple(envelope * s * np.sin(2 * np.pi * plan.liftoff_wobble_hz * dt + p)  # type: ignore[return-value]
                 for s, p in zip(scale, phase, strict=True))
