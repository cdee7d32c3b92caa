"""Processing configuration: defaults, ``flight.toml`` and command-line overrides.

Units: metres for lever arms and GNSS sigmas, degrees for the boresight, hours for the UTC offset.
"""

from __future__ import annotations

import json
import tomllib
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from georef.imu_errors import ImuErrorModel, imu_preset
from georef.io.errors import InputError

METHODS = ("rts", "ekf", "axis", "graph")


@dataclass(frozen=True)
class ProcessingConfig:
    """Everything ``georef process`` needs besides the input files."""

    method: str = "rts"
    #: roll/pitch from the POS unit ("unit") or recomputed from the raw IMU by the MEKF ("imu")
    attitude_source: str = "unit"
    #: body-frame lever arm IMU -> GNSS antenna [m], x forward, y right, z down
    lever_arm_gnss: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: body-frame lever arm IMU -> camera perspective centre [m]
    lever_arm_camera: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: boresight (roll, pitch, yaw) of the camera in the body frame [deg]
    boresight: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: GNSS fix standard deviation north, east, up [m]
    gnss_sigma: tuple[float, float, float] = (1.0, 1.0, 2.0)
    #: GNSS fix rate [Hz] when known (enables keeping equal consecutive fixes); None = unknown
    gnss_rate_hz: float | None = 1.0
    #: UTC offset of the camera's local clock [h] (raw camera logs only; no default on purpose)
    camera_utc_offset: float | None = None
    #: camera trigger latency [s]: the exposure happened this long after its logged time
    camera_time_offset: float = 0.0
    #: GNSS time-tag latency [s]: each fix was measured this long before its time tag. None: 0 is used, and the
    #: latency the data show is estimated and reported (quality check) but not applied
    gnss_latency: float | None = None
    #: magnetic declination [deg, east positive] for a magnetometer heading (imu.csv with mag_x..z)
    magnetic_declination: float = 0.0
    #: "auto" (non-holonomic constraints when the motion shows a ground vehicle), "ground" or "air"
    vehicle: str = "auto"
    #: projected CRS for easting/northing, e.g. "EPSG:3765", or a compound CRS with its height system
    #: ("EPSG:3765+5773"; then ``height = "orthometric"``)
    crs: str | None = None
    #: heights of the exports: "ellipsoidal" (WGS 84) or "orthometric" (``vertical_crs``, or the compound CRS's)
    height: str = "ellipsoidal"
    #: vertical CRS of orthometric heights when ``crs`` has none (EPSG:5773 = EGM96 height)
    vertical_crs: str = "EPSG:5773"
    #: image file names: a pattern such as "IMG_{frame:04d}.JPG" or a two-column CSV (frame, name)
    image_names: str | None = None
    #: write the camera's yaw/pitch/roll into OpenDroneMap's geo.txt (default: NaN, see docs/formats.md)
    odm_angles: bool = False
    #: POS column role -> header name remapping
    pos_columns: dict[str, str] = field(default_factory=dict)
    #: camera column role (number, time, milliseconds) -> header name remapping (Kamera.txt or the raw log)
    camera_columns: dict[str, str] = field(default_factory=dict)
    #: yaw-offset recovery: window length [s], window step [s] and drift-smoothing bandwidth [s]
    yaw_window: float = 60.0
    yaw_step: float = 15.0
    yaw_bandwidth: float = 300.0
    #: 1-sigma accuracy of the unit's own roll/pitch [deg] and of its yaw relative to its origin [deg]
    unit_level_sigma: float = 0.1
    unit_yaw_sigma: float = 0.05
    #: correlation time of the unit's roll/pitch error [s]; white noise of its angles [deg]
    unit_level_time: float = 60.0
    unit_angle_noise: float = 0.02
    #: how fast the drift of the unit's yaw origin may change [deg/min per sqrt(min)]
    unit_drift_change: float = 0.05
    #: full-state filters: fuse the unit's own roll/pitch/yaw (when POS.txt has them) with modelled errors
    unit_aiding: bool = True
    #: per-axis filter: white acceleration noise per sample [m/s^2] (None = estimated from the data)
    axis_accel_sigma: float | None = None
    #: per-axis filter: slowly varying acceleration error (bias, yaw-offset error) [m/s^2] and its time [s]
    axis_bias_sigma: float = 0.025
    axis_bias_time: float = 60.0
    #: innovation gate: chi-square threshold of a 3-D GNSS position innovation (16.27 = 99.9 %)
    gate_chi2: float = 16.27
    #: full-state filters: IMU error preset (see georef.imu_errors) and datasheet overrides
    imu_preset: str = "mems-ivru"
    imu_model: dict[str, float] = field(default_factory=dict)
    #: covariance propagation rate of the full-state filters [Hz] (every GNSS fix is an epoch too); with the
    #: third-order discretisation 1, 2, 5 and 10 Hz give the same accuracy and sigmas (docs/method-ins.md)
    covariance_rate: float = 2.0
    #: factor-graph solver: "lm" (batch Levenberg-Marquardt) or "isam2" (incremental)
    graph_solver: str = "lm"
    #: factor graph: Cauchy robust kernel on the GNSS factors (False: plain Gaussian)
    graph_robust: bool = True
    #: factor graph: 1-sigma prior [unitless; 0.002 = 2000 ppm] of the gyro and accelerometer scale-factor errors,
    #: estimated with the trajectory where the motion makes them observable (a turn for the yaw gyro). 0 (default):
    #: not estimated; on flights without scale-factor errors estimating them cost up to 4.5 % horizontal RMS
    #: (docs/method-graph.md)
    graph_scale_factor_sigma: float = 0.0
    #: [m] 1-sigma of the given GNSS lever arm as the graph's prior on its lever-arm variable, one number or one per
    #: body axis. None: 0.05 m (a taped installation) when a lever arm is given (non-zero), else estimated freely
    #: (10 m)
    lever_arm_gnss_sigma: float | tuple[float, float, float] | None = None
    #: [s] 1-sigma of the given ``gnss_latency`` as the graph's prior on its GNSS time-offset variable. None: 0.01 s
    #: when a latency is given, else zero with 0.002 s (a PPS-synchronised log; set 0.5 to estimate it freely)
    gnss_latency_sigma: float | None = None
    #: the graph's prior on (lever arm x, y, z [m, body], GNSS time offset [s]) as ``(mean (4,), covariance
    #: (4, 4))``, replacing the two priors above: set by ``georef batch --shared-calibration`` from the campaign's
    #: other flights (docs/method-graph.md); not a flight.toml key
    calibration_prior: tuple | None = None

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"unknown method {self.method!r}; choose one of {', '.join(METHODS)}")
        if not 0.0 <= self.graph_scale_factor_sigma <= 0.1:
            raise ValueError("graph_scale_factor_sigma must be between 0 (not estimated) and 0.1 (10 %), got "
                             f"{self.graph_scale_factor_sigma!r}")
        if self.graph_solver not in ("lm", "isam2"):
            raise ValueError(f"graph_solver must be 'lm' or 'isam2', got {self.graph_solver!r}")
        if self.vehicle not in ("auto", "ground", "air"):
            raise ValueError(f"vehicle must be 'auto', 'ground' or 'air', got {self.vehicle!r}")
        if self.height not in ("ellipsoidal", "orthometric"):
            raise ValueError(f"height must be 'ellipsoidal' or 'orthometric', got {self.height!r}")
        if self.attitude_source not in ("unit", "imu"):
            raise ValueError(f"attitude_source must be 'unit' or 'imu', got {self.attitude_source!r}")
        for name in ("lever_arm_gnss", "lever_arm_camera", "boresight", "gnss_sigma"):
            value = getattr(self, name)
            if len(value) != 3:
                raise ValueError(f"{name} needs three numbers, got {value!r}")
            object.__setattr__(self, name, tuple(float(v) for v in value))
        if self.covariance_rate <= 0:
            raise ValueError(f"covariance_rate must be positive Hz, got {self.covariance_rate}")
        sigma = self.lever_arm_gnss_sigma
        if sigma is not None:
            values = np.atleast_1d(np.asarray(sigma, float))
            if values.shape not in ((1,), (3,)) or (values <= 0).any():
                raise ValueError(f"lever_arm_gnss_sigma needs one or three positive metres, got {sigma!r}")
            object.__setattr__(self, "lever_arm_gnss_sigma", float(values[0]) if values.shape == (1,)
                               else tuple(float(v) for v in values))
        if self.gnss_latency_sigma is not None and self.gnss_latency_sigma <= 0:
            raise ValueError(f"gnss_latency_sigma must be positive seconds, got {self.gnss_latency_sigma}")
        if min(self.gnss_sigma) <= 0:
            raise ValueError(f"gnss_sigma must be positive metres, got {self.gnss_sigma}")

    def imu_error_model(self) -> ImuErrorModel:
        """The datasheet error model: the preset with any ``[imu]`` overrides."""
        return replace(imu_preset(self.imu_preset), **self.imu_model)

    def updated(self, **changes: Any) -> ProcessingConfig:
        """A copy with the given fields changed (``None`` values are ignored)."""
        return replace(self, **{k: v for k, v in changes.items() if v is not None})


#: TOML section -> keys it may hold (all map onto ProcessingConfig fields of the same name).
_SECTIONS = {
    "processing": {"method", "attitude_source"},
    "mounting": {"lever_arm_gnss", "lever_arm_camera", "boresight", "lever_arm_gnss_sigma"},
    "gnss": {"gnss_sigma", "gnss_rate_hz", "gnss_latency", "gnss_latency_sigma"},
    "camera": {"camera_utc_offset", "camera_time_offset"},
    "output": {"crs", "height", "vertical_crs", "image_names", "odm_angles"},
    "yaw_offset": {"yaw_window", "yaw_step", "yaw_bandwidth"},
    "unit": {"unit_level_sigma", "unit_yaw_sigma", "unit_level_time", "unit_angle_noise", "unit_drift_change",
             "unit_aiding"},
    "axis": {"axis_accel_sigma", "axis_bias_sigma", "axis_bias_time"},
    "gnss_gate": {"gate_chi2"},
    "ins": {"imu_preset", "covariance_rate", "magnetic_declination", "vehicle"},
    "graph": {"graph_solver", "graph_robust", "graph_scale_factor_sigma"},
}


def load_config(path: Path | str, base: ProcessingConfig | None = None) -> ProcessingConfig:
    """Read a ``flight.toml``; unknown sections or keys are errors that name them."""
    path = Path(path)
    if not path.exists():
        raise InputError(path, None, None, "configuration file not found")
    try:
        document = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        line = getattr(exc, "lineno", None)
        raise InputError(path, line, None, f"not valid TOML: {exc}") from None
    values: dict[str, Any] = {}
    known_fields = {f.name for f in fields(ProcessingConfig)}
    for section, content in document.items():
        if section == "pos_columns":
            values["pos_columns"] = {str(k): str(v) for k, v in content.items()}
            continue
        if section == "camera_columns":
            from georef.io.camera import CAMERA_ROLES

            if not isinstance(content, dict):
                raise InputError(path, None, section, "[camera_columns] holds role = \"header name\" lines")
            for key, value in content.items():
                if key not in CAMERA_ROLES:
                    raise InputError(path, None, f"camera_columns.{key}",
                                     f"unknown camera column role; known: {', '.join(CAMERA_ROLES)}")
                if not isinstance(value, str) or not value.strip():
                    raise InputError(path, None, f"camera_columns.{key}", "give the header name as a string")
            values["camera_columns"] = {str(k): str(v) for k, v in content.items()}
            continue
        if section == "imu":
            known = {f.name for f in fields(ImuErrorModel)}
            unknown = [k for k in content if k not in known]
            if unknown:
                raise InputError(path, None, f"imu.{unknown[0]}",
                                 f"unknown key; [imu] takes {', '.join(sorted(known))}")
            values["imu_model"] = {str(k): float(v) for k, v in content.items()}
            continue
        if section not in _SECTIONS or not isinstance(content, dict):
            raise InputError(path, None, section, f"unknown section [{section}]; known: "
                             f"{', '.join([*_SECTIONS, 'pos_columns', 'camera_columns', 'imu'])}")
        for key, value in content.items():
            if section == "ins" and key == "imu_noise_from_data":
                raise InputError(path, None, "ins.imu_noise_from_data", "this setting was removed: the noise model "
                                 "is now always fitted to the data (docs/method-ins.md); delete the line")
            if key not in _SECTIONS[section] or key not in known_fields:
                raise InputError(path, None, f"{section}.{key}", f"unknown key; [{section}] takes "
                                 f"{', '.join(sorted(_SECTIONS[section]))}")
            values[key] = tuple(value) if isinstance(value, list) else value
            if key == "image_names" and isinstance(value, str) and "{" not in value and not Path(value).is_absolute():
                values[key] = str(path.parent / value)  # a name table beside flight.toml, wherever georef runs
    try:
        return replace(base or ProcessingConfig(), **values)
    except (TypeError, ValueError) as exc:
        raise InputError(path, None, None, str(exc)) from None


def load_configs(paths: list[Path] | list[str] | Path | str | None) -> ProcessingConfig:
    """Read ``flight.toml`` files in order, each later one changing only the keys it names (``None`` or an empty
    list: the defaults)."""
    if paths is None:
        return ProcessingConfig()
    cfg = ProcessingConfig()
    for path in [paths] if isinstance(paths, (str, Path)) else paths:
        cfg = load_config(path, base=cfg)
    return cfg


def config_to_toml(cfg: ProcessingConfig) -> str:
    """The configuration as a ``flight.toml`` document (non-default and commonly edited values)."""

    def fmt(value: Any) -> str:
        if isinstance(value, tuple):
            return "[" + ", ".join(f"{v:g}" for v in value) + "]"
        if isinstance(value, str):
            return f'"{value}"'
        if isinstance(value, bool):
            return "true" if value else "false"
        return f"{value:g}" if isinstance(value, float) else str(value)

    out = []
    for section, keys in _SECTIONS.items():
        rows = [f"{key} = {fmt(getattr(cfg, key))}" for key in sorted(keys) if getattr(cfg, key) is not None]
        if rows:
            out.append(f"[{section}]\n" + "\n".join(rows))
    if cfg.pos_columns:
        out.append("[pos_columns]\n" + "\n".join(f'{k} = "{v}"' for k, v in cfg.pos_columns.items()))
    if cfg.camera_columns:
        out.append("[camera_columns]\n" + "\n".join(f"{k} = {json.dumps(v)}" for k, v in cfg.camera_columns.items()))
    if cfg.imu_model:
        out.append("[imu]\n" + "\n".join(f"{k} = {v:g}" for k, v in cfg.imu_model.items()))
    return "\n\n".join(out) + "\n"
