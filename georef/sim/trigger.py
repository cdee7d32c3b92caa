"""A drone's camera trigger: events logged when the trigger is sent, exposures a latency later.

An autopilot triggers the camera every ``distance_m`` flown (or every ``interval_s``) while it flies a survey leg,
and logs the event in the control loop that sends the trigger, on the IMU's time scale. The camera exposes
``latency_s`` (0.1-0.2 s on consumer cameras) after that: at 10 m/s, about 1.5 m further along the leg than the
logged time says. The truth belongs to the exposure, the event file holds the logged time.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.integrate import cumulative_trapezoid

TRIGGER_MODES = ("distance", "time")


@dataclass
class CameraTriggerModel:
    """Camera triggering during the survey legs. Units: m, s.

    ``mode``: ``distance`` (an event every ``distance_m`` of horizontal distance flown along a leg, the first at
    the leg's start) or ``time`` (every ``interval_s`` from the leg's start). Events fall on IMU rows (the
    autopilot's loop). Exposure = event + ``latency_s`` + uniform jitter within ``+-latency_jitter_s``. Image
    names ``image_pattern.format(frame)`` (frames 1, 2, ...).
    """

    mode: str = "distance"
    distance_m: float = 15.0
    interval_s: float = 2.0
    latency_s: float = 0.15
    latency_jitter_s: float = 0.002
    image_pattern: str = "IMG_{:04d}.JPG"

    def __post_init__(self) -> None:
        if self.mode not in TRIGGER_MODES:
            raise ValueError(f"camera trigger mode must be one of {', '.join(TRIGGER_MODES)}, got {self.mode!r}")
        if self.distance_m <= 0 or self.interval_s <= 0 or self.latency_s < 0 or self.latency_jitter_s < 0:
            raise ValueError("camera trigger: distance and interval must be positive, latency and jitter >= 0")


@dataclass
class CameraEvents:
    """Logged trigger times and true exposure times [s] (K,), log time scale, and the image names."""

    trigger_time: np.ndarray
    exposure_time: np.ndarray
    image: list[str]


def camera_events(model: CameraTriggerModel, legs: list[tuple[float, float]], row_time: np.ndarray,
                  v_n: np.ndarray, rng: np.random.Generator) -> CameraEvents:
    """Events during the ``legs`` ((start, end) [s], log time scale) from the IMU rows ``row_time`` [s] and the
    true NED velocity there ``v_n`` [m/s] (N, 3). Exposures after the last row are dropped."""
    triggers = []
    for start, end in legs:
        inside = np.flatnonzero((row_time >= start) & (row_time <= end))
        if len(inside) == 0:
            continue
        if model.mode == "distance":
            speed = np.hypot(v_n[inside, 0], v_n[inside, 1])
            count = np.floor(cumulative_trapezoid(speed, row_time[inside], initial=0.0) / model.distance_m)
        else:
            count = np.floor((row_time[inside] - row_time[inside[0]]) / model.interval_s)
        first_of_count = np.concatenate([[True], np.diff(count) > 0])
        triggers.append(row_time[inside[first_of_count]])
    trigger_time = np.concatenate(triggers) if triggers else np.empty(0)
    exposure = trigger_time + model.latency_s + rng.uniform(-model.latency_jitter_s, model.latency_jitter_s,
                                                            len(trigger_time))
    keep = exposure <= row_time[-1]
    trigger_time, exposure = trigger_time[keep], exposure[keep]
    images = [model.image_pattern.format(k) for k in range(1, len(trigger_time) + 1)]
    return CameraEvents(trigger_time=trigger_time, exposure_time=exposure, image=images)
