"""Processing configuration: defaults, ``flight.toml`` and command-line overrides.

:class:`ProcessingConfig` is the composition of one frozen dataclass per ``flight.toml`` section
(``cfg.mounting.lever_arm_gnss``, ``cfg.gnss.sigma``, ``cfg.graph.solver`` ...); each section checks its own
values and names the failing one as ``section.key`` (the key a ``flight.toml`` spells it with). The solvers take
only the sections they read (:class:`InsSettings`, :class:`AxisSettings`, :class:`GraphSettings`).

Units: metres for lever arms and GNSS sigmas, degrees for the boresight and the unit's angles, hours for the
camera's UTC offset, seconds for times and latencies.
"""

from __future__ import annotations

import json
import re
import tomllib
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from georef.distributions import CHI2_3DOF_99_9
from georef.imu_errors import IMU_PRESETS, ImuErrorModel, imu_preset
from georef.io.errors import InputError

METHODS = ("rts", "ekf", "axis", "graph")
#: ``[ins] vehicle`` (``--vehicle``): "auto" (non-holonomic constraints when the motion shows a ground vehicle),
#: "ground" or "air"
VEHICLE_KINDS = ("auto", "ground", "air")

#: field metadata: the field's ``flight.toml`` key when it differs from the field's name
_TOML = "toml"


class ConfigValueError(ValueError):
    """A configuration value a section refuses; ``key`` is its ``section.key`` as ``flight.toml`` spells it."""

    def __init__(self, key: str, message: str) -> None:
        super().__init__(message)
        self.key = key


def _key(f: Any) -> str:
    """The ``flight.toml`` key of a section's field."""
    return f.metadata.get(_TOML, f.name)


def _toml(name: str, default: Any = None, **kwargs: Any) -> Any:
    """A section field whose ``flight.toml`` key is ``name``."""
    return field(default=default, metadata={_TOML: name}, **kwargs)


#: the Python types a field's annotation admits (ints are admitted where floats are: TOML writes 60 for 60.0)
_ADMITTED: dict[str, tuple[type, ...]] = {
    "float": (int, float), "float | None": (int, float, type(None)), "str": (str,), "str | None": (str, type(None)),
    "bool": (bool,),
}


class _Section:
    """Shared checks of the scalar sections: each value's type, and a message naming ``section.key``."""

    SECTION: ClassVar[str]

    def _fail(self, name: str, message: str) -> None:
        key = f"{self.SECTION}.{_key(next(f for f in fields(self) if f.name == name))}"  # type: ignore[arg-type]
        raise ConfigValueError(key, f"{key} {message}")

    def _check_types(self) -> None:
        for f in fields(self):  # type: ignore[arg-type]
            admitted = _ADMITTED.get(str(f.type))
            value = getattr(self, f.name)
            if admitted is not None and (not isinstance(value, admitted) or (bool not in admitted
                                                                               and isinstance(value, bool))):
                self._fail(f.name, f"must be {str(f.type).replace(' | None', ' or absent')}, got {value!r}")
            # NaN passes every comparison check and froze the alignment's iterations (a NaN GNSS latency ran
            # forever); infinity is no setting either
            numbers = value if isinstance(value, (tuple, list)) else (value,)
            if any(isinstance(v, float) and not np.isfinite(v) for v in numbers):
                self._fail(f.name, f"must be finite, got {value!r}")

    def _triple(self, name: str, what: str) -> None:
        """Three numbers (``what``: their unit) stored as a tuple of floats."""
        value = getattr(self, name)
        try:
            if isinstance(value, (str, bytes)) or len(value) != 3 or any(isinstance(v, bool) for v in value):
                raise TypeError
            triple = tuple(float(v) for v in value)
        except (TypeError, ValueError):
            self._fail(name, f"needs three numbers [{what}], got {value!r}")
        if not all(np.isfinite(triple)):
            self._fail(name, f"needs three finite numbers [{what}], got {value!r}")
        object.__setattr__(self, name, triple)

    def _choice(self, name: str, choices: tuple[str, ...]) -> None:
        value = getattr(self, name)
        if value not in choices:
            named = [repr(c) for c in choices]
            self._fail(name, f"must be {', '.join(named[:-1])} or {named[-1]}, got {value!r}")

    def _positive(self, name: str, unit: str) -> None:
        value = getattr(self, name)
        if value is not None and not value > 0:
            self._fail(name, f"must be positive {unit}, got {value!r}")


@dataclass(frozen=True)
class ProcessingSection(_Section):
    """``[processing]``: the fusion method and where roll and pitch come from."""

    SECTION: ClassVar[str] = "processing"
    #: "rts" (EKF + RTS smoother), "ekf" (forward filter), "axis" (per-axis method) or "graph" (factor graph)
    method: str = "rts"
    #: roll/pitch from the POS unit ("unit") or recomputed from the raw IMU by the MEKF ("imu")
    attitude_source: str = "unit"

    def __post_init__(self) -> None:
        self._check_types()
        self._choice("method", METHODS)
        self._choice("attitude_source", ("unit", "imu"))


@dataclass(frozen=True)
class MountingSection(_Section):
    """``[mounting]``: where the antenna and the camera sit on the IMU's body frame (x forward, y right, z down)."""

    SECTION: ClassVar[str] = "mounting"
    #: body-frame lever arm IMU -> GNSS antenna [m], x forward, y right, z down
    lever_arm_gnss: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: body-frame lever arm IMU -> camera perspective centre [m]
    lever_arm_camera: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: boresight (roll, pitch, yaw) of the camera in the body frame [deg]
    boresight: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: [m] 1-sigma of the given GNSS lever arm as the graph's prior on its lever-arm variable, one number or one per
    #: body axis. None: 0.05 m (a taped installation) when a lever arm is given (non-zero), else estimated freely
    #: (10 m)
    lever_arm_gnss_sigma: float | tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        self._triple("lever_arm_gnss", "m")
        self._triple("lever_arm_camera", "m")
        self._triple("boresight", "deg")
        sigma = self.lever_arm_gnss_sigma
        if sigma is not None:
            try:
                values = np.atleast_1d(np.asarray(sigma, float))
            except (TypeError, ValueError):
                values = np.zeros(0)
            if isinstance(sigma, (bool, str)) or values.shape not in ((1,), (3,)) or not (values > 0).all():
                self._fail("lever_arm_gnss_sigma", f"needs one or three positive metres, got {sigma!r}")
            object.__setattr__(self, "lever_arm_gnss_sigma", float(values[0]) if values.shape == (1,)
                               else tuple(float(v) for v in values))


@dataclass(frozen=True)
class GnssSection(_Section):
    """``[gnss]``: the GNSS fixes' accuracy, rate and time tags."""

    SECTION: ClassVar[str] = "gnss"
    #: GNSS fix standard deviation north, east, up [m], for fixes without their own sigmas
    sigma: tuple[float, float, float] = _toml("gnss_sigma", (1.0, 1.0, 2.0))
    #: GNSS fix rate [Hz] when known (enables keeping equal consecutive fixes); None = unknown
    rate_hz: float | None = _toml("gnss_rate_hz", 1.0)
    #: GNSS time-tag latency [s]: each fix was measured this long before its time tag. None: 0 is used, and the
    #: latency the data show is estimated and reported (quality check) but not applied
    latency: float | None = _toml("gnss_latency", None)
    #: [s] 1-sigma of the given ``latency`` as the graph's prior on its GNSS time-offset variable. None: 0.01 s
    #: when a latency is given, else zero with 0.002 s (a PPS-synchronised log; set 0.5 to estimate it freely)
    latency_sigma: float | None = _toml("gnss_latency_sigma", None)
    #: [s] correlation time of the fixes' errors (a receiver's position wanders over tens of seconds); the
    #: full-state filters carry that wander as a first-order Gauss-Markov state and fit its size. 0: white errors
    correlation_time: float = _toml("gnss_correlation_time", 60.0)

    def __post_init__(self) -> None:
        self._check_types()
        self._triple("sigma", "m")
        if not self.correlation_time >= 0:
            self._fail("correlation_time", f"must be 0 (white errors) or positive seconds, got {self.correlation_time}")
        if min(self.sigma) <= 0:
            self._fail("sigma", f"must be positive metres, got {self.sigma}")
        self._positive("rate_hz", "Hz")
        self._positive("latency_sigma", "seconds")


@dataclass(frozen=True)
class CameraSection(_Section):
    """``[camera]``: the camera's clock."""

    SECTION: ClassVar[str] = "camera"
    #: UTC offset of the camera's local clock [h] (raw camera logs only; no default on purpose)
    utc_offset: float | None = _toml("camera_utc_offset", None)
    #: camera trigger latency [s]: the exposure happened this long after its logged time
    time_offset: float = _toml("camera_time_offset", 0.0)
    #: [s] 1-sigma of the exposure times (after the latency), for every frame; None: each source's own (0 for
    #: Kamera.txt, the camera's feedback of an autopilot log a few ms, its trigger commands and events.csv 0.1 s)
    time_sigma: float | None = _toml("camera_time_sigma", None)

    def __post_init__(self) -> None:
        self._check_types()
        if self.time_sigma is not None and not self.time_sigma >= 0:
            self._fail("time_sigma", f"must be 0 or positive seconds, got {self.time_sigma}")


@dataclass(frozen=True)
class OutputSection(_Section):
    """``[output]``: the coordinates, heights and image names of the EO table and the exports."""

    SECTION: ClassVar[str] = "output"
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

    def __post_init__(self) -> None:
        self._check_types()
        self._choice("height", ("ellipsoidal", "orthometric"))


@dataclass(frozen=True)
class YawOffsetSection(_Section):
    """``[yaw_offset]``: recovery of the POS unit's yaw offset from GNSS (per-axis method, heading fallback)."""

    SECTION: ClassVar[str] = "yaw_offset"
    #: window length [s]
    window: float = _toml("yaw_window", 60.0)
    #: window step [s]
    step: float = _toml("yaw_step", 15.0)
    #: drift-smoothing bandwidth [s]
    bandwidth: float = _toml("yaw_bandwidth", 300.0)

    def __post_init__(self) -> None:
        self._check_types()
        for name in ("window", "step", "bandwidth"):
            self._positive(name, "seconds")


@dataclass(frozen=True)
class UnitSection(_Section):
    """``[unit]``: the error model of the POS unit's own roll, pitch and yaw, and whether they aid the filters."""

    SECTION: ClassVar[str] = "unit"
    #: 1-sigma accuracy of the unit's own roll/pitch [deg]
    level_sigma: float = _toml("unit_level_sigma", 0.1)
    #: 1-sigma accuracy of the unit's yaw relative to its origin [deg]
    yaw_sigma: float = _toml("unit_yaw_sigma", 0.05)
    #: correlation time of the unit's roll/pitch error [s]
    level_time: float = _toml("unit_level_time", 60.0)
    #: white noise of the unit's angles [deg]
    angle_noise: float = _toml("unit_angle_noise", 0.02)
    #: how fast the drift of the unit's yaw origin may change [deg/min per sqrt(min)]. 0.05 held the drift so
    #: nearly constant that, on flights whose only heading information is one turn, the z-gyro bias took up what
    #: the unit's yaw and the INS disagreed on, and the yaw sigmas were overconfident; 0.2 makes them honest with
    #: less yaw error (benchmarks/honesty.py; docs/performance.md, "The unit's yaw drift"; docs/method-ins.md
    #: section 9)
    drift_change: float = _toml("unit_drift_change", 0.2)
    #: full-state filters: fuse the unit's own roll/pitch/yaw (when POS.txt has them) with modelled errors
    aiding: bool = _toml("unit_aiding", True)

    def __post_init__(self) -> None:
        self._check_types()
        for name in ("level_sigma", "yaw_sigma", "angle_noise"):
            self._positive(name, "degrees")
        self._positive("level_time", "seconds")
        if self.drift_change < 0:
            self._fail("drift_change", f"must not be negative, got {self.drift_change!r}")


@dataclass(frozen=True)
class AxisSection(_Section):
    """``[axis]``: the per-axis filter's acceleration noise."""

    SECTION: ClassVar[str] = "axis"
    #: white acceleration noise per sample [m/s^2] (None = estimated from the data)
    accel_sigma: float | None = _toml("axis_accel_sigma", None)
    #: slowly varying acceleration error (bias, yaw-offset error) [m/s^2]
    bias_sigma: float = _toml("axis_bias_sigma", 0.025)
    #: its correlation time [s]
    bias_time: float = _toml("axis_bias_time", 60.0)

    def __post_init__(self) -> None:
        self._check_types()
        self._positive("accel_sigma", "m/s^2")
        self._positive("bias_sigma", "m/s^2")
        self._positive("bias_time", "seconds")


@dataclass(frozen=True)
class GnssGateSection(_Section):
    """``[gnss_gate]``: the innovation gate of the GNSS fixes."""

    SECTION: ClassVar[str] = "gnss_gate"
    #: chi-square threshold of a 3-D GNSS position innovation (99.9 %)
    chi2: float = _toml("gate_chi2", CHI2_3DOF_99_9)

    def __post_init__(self) -> None:
        self._check_types()
        self._positive("chi2", "(a chi-square threshold)")


@dataclass(frozen=True)
class InsSection(_Section):
    """``[ins]``: the full-state filters' IMU model, covariance rate, heading aid and vehicle."""

    SECTION: ClassVar[str] = "ins"
    #: IMU error preset (see georef.imu_errors); ``[imu]`` overrides its datasheet values
    imu_preset: str = "mems-ivru"
    #: covariance propagation rate [Hz] (every GNSS fix is an epoch too); with the third-order discretisation
    #: 1, 2, 5 and 10 Hz give the same accuracy and sigmas (docs/method-ins.md)
    covariance_rate: float = 2.0
    #: magnetic declination [deg, east positive] for a magnetometer heading (imu.csv with mag_x..z)
    magnetic_declination: float = 0.0
    #: "auto" (non-holonomic constraints when the motion shows a ground vehicle), "ground" or "air"
    vehicle: str = "auto"

    def __post_init__(self) -> None:
        self._check_types()
        if self.imu_preset not in IMU_PRESETS:
            self._fail("imu_preset", f"is not a known IMU preset ({', '.join(IMU_PRESETS)}), got {self.imu_preset!r}")
        self._positive("covariance_rate", "Hz")
        self._choice("vehicle", VEHICLE_KINDS)


@dataclass(frozen=True)
class GraphSection(_Section):
    """``[graph]``: the factor-graph smoother (``--method graph``)."""

    SECTION: ClassVar[str] = "graph"
    #: "lm" (batch Levenberg-Marquardt) or "isam2" (incremental)
    solver: str = _toml("graph_solver", "lm")
    #: Cauchy robust kernel on the GNSS factors (False: plain Gaussian)
    robust: bool = _toml("graph_robust", True)
    #: 1-sigma prior [unitless; 0.002 = 2000 ppm] of the gyro and accelerometer scale-factor errors, estimated with
    #: the trajectory where the motion makes them observable (a turn for the yaw gyro). 0 (default): not
    #: estimated; on flights without scale-factor errors estimating them cost horizontal accuracy
    #: (docs/method-graph.md, "Calibration, measured")
    scale_factor_sigma: float = _toml("graph_scale_factor_sigma", 0.0)

    def __post_init__(self) -> None:
        self._check_types()
        self._choice("solver", ("lm", "isam2"))
        if not 0.0 <= self.scale_factor_sigma <= 0.1:
            self._fail("scale_factor_sigma", "must be between 0 (not estimated) and 0.1 (10 %), got "
                       f"{self.scale_factor_sigma!r}")


def _names_map(section: str, names: Any, roles: tuple[str, ...] | None) -> dict[str, str]:
    """A ``role = "header name"`` table checked: known roles (when ``roles`` is given), non-empty strings."""
    if not isinstance(names, dict):
        raise ConfigValueError(section, f"[{section}] holds role = \"header name\" lines, got {names!r}")
    for role, name in names.items():
        if roles is not None and role not in roles:
            raise ConfigValueError(f"{section}.{role}", f"{section}.{role}: unknown {section.split('_')[0]} column "
                                   f"role; known: {', '.join(roles)}")
        if not isinstance(name, str) or not name.strip():
            raise ConfigValueError(f"{section}.{role}", f"{section}.{role}: give the header name as a string, "
                                   f"got {name!r}")
    return {str(k): v for k, v in names.items()}


@dataclass(frozen=True)
class PosColumns:
    """``[pos_columns]``: POS column role -> header name remapping (roles: docs/formats.md)."""

    SECTION: ClassVar[str] = "pos_columns"
    names: dict[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "names", _names_map(self.SECTION, self.names, None))


@dataclass(frozen=True)
class CameraColumns:
    """``[camera_columns]``: camera column role (number, time, milliseconds) -> header name remapping (Kamera.txt
    or the raw log)."""

    SECTION: ClassVar[str] = "camera_columns"
    names: dict[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        from georef.io.camera import CAMERA_ROLES

        object.__setattr__(self, "names", _names_map(self.SECTION, self.names, tuple(CAMERA_ROLES)))


@dataclass(frozen=True)
class ImuSection:
    """``[imu]``: datasheet values replacing those of the ``ins.imu_preset`` (keys: the fields of
    :class:`georef.imu_errors.ImuErrorModel`, in their units)."""

    SECTION: ClassVar[str] = "imu"
    overrides: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        known = [f.name for f in fields(ImuErrorModel)]
        if not isinstance(self.overrides, dict):
            raise ConfigValueError("imu", f"[imu] holds datasheet values ({', '.join(sorted(known))}), got "
                                   f"{self.overrides!r}")
        for key, value in self.overrides.items():
            if key not in known:
                raise ConfigValueError(f"imu.{key}", f"imu.{key}: unknown key; [imu] takes {', '.join(sorted(known))}")
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ConfigValueError(f"imu.{key}", f"imu.{key} must be a number, got {value!r}")
        object.__setattr__(self, "overrides", {str(k): float(v) for k, v in self.overrides.items()})

    def error_model(self, preset: str) -> ImuErrorModel:
        """The datasheet error model: the preset called ``preset`` with these overrides."""
        return replace(imu_preset(preset), **self.overrides)


#: the sections in flight.toml order: ProcessingConfig's field name = the TOML section's name
_SECTION_TYPES: dict[str, type] = {
    "processing": ProcessingSection, "mounting": MountingSection, "gnss": GnssSection, "camera": CameraSection,
    "output": OutputSection, "yaw_offset": YawOffsetSection, "unit": UnitSection, "axis": AxisSection,
    "gnss_gate": GnssGateSection, "ins": InsSection, "graph": GraphSection, "pos_columns": PosColumns,
    "camera_columns": CameraColumns, "imu": ImuSection,
}
#: the sections holding a table of their own (role -> name, datasheet key -> value) rather than fixed keys
_MAP_SECTIONS = {"pos_columns": "names", "camera_columns": "names", "imu": "overrides"}
#: flight.toml key -> (section, field name) of the scalar sections (every key is unique across sections)
_KEYS: dict[str, tuple[str, str]] = {
    _key(f): (section, f.name)
    for section, kind in _SECTION_TYPES.items() if section not in _MAP_SECTIONS for f in fields(kind)
}


@dataclass(frozen=True)
class ProcessingConfig:
    """Everything ``georef process`` needs besides the input files: one section per ``flight.toml`` section.

    Build one from defaults and ``flight.toml`` keys, ``ProcessingConfig().updated(lever_arm_gnss=(0.4, 0.1,
    -1.6))``, or from sections, ``ProcessingConfig(mounting=MountingSection(lever_arm_gnss=(0.4, 0.1, -1.6)))``.
    """

    processing: ProcessingSection = field(default_factory=ProcessingSection)
    mounting: MountingSection = field(default_factory=MountingSection)
    gnss: GnssSection = field(default_factory=GnssSection)
    camera: CameraSection = field(default_factory=CameraSection)
    output: OutputSection = field(default_factory=OutputSection)
    yaw_offset: YawOffsetSection = field(default_factory=YawOffsetSection)
    unit: UnitSection = field(default_factory=UnitSection)
    axis: AxisSection = field(default_factory=AxisSection)
    gnss_gate: GnssGateSection = field(default_factory=GnssGateSection)
    ins: InsSection = field(default_factory=InsSection)
    graph: GraphSection = field(default_factory=GraphSection)
    pos_columns: PosColumns = field(default_factory=PosColumns)
    camera_columns: CameraColumns = field(default_factory=CameraColumns)
    imu: ImuSection = field(default_factory=ImuSection)

    def __post_init__(self) -> None:
        for name, kind in _SECTION_TYPES.items():
            if not isinstance(getattr(self, name), kind):
                raise TypeError(f"ProcessingConfig.{name} must be a {kind.__name__}, got {getattr(self, name)!r}")

    def items(self) -> list[tuple[str, str, Any]]:
        """Every setting as ``(section, flight.toml key, value)``, in ``flight.toml`` order (sections in the
        order above, keys sorted); the tables ``pos_columns``, ``camera_columns`` and ``imu`` as one item each
        whose key is the section's name and whose value is their ``dict``."""
        out: list[tuple[str, str, Any]] = []
        for section, kind in _SECTION_TYPES.items():
            content = getattr(self, section)
            if section in _MAP_SECTIONS:
                out.append((section, section, getattr(content, _MAP_SECTIONS[section])))
            else:
                out += sorted((section, _key(f), getattr(content, f.name)) for f in fields(kind))
        return out

    def settings(self) -> dict[str, Any]:
        """Every setting by its ``flight.toml`` key (``{"lever_arm_gnss": (...), "gnss_sigma": (...), ...}``), as
        the run summaries list them; the ``[imu]`` table under ``imu_model``, its name in the summaries."""
        return {("imu_model" if key == "imu" else key): value for _, key, value in self.items()}

    def updated(self, **changes: Any) -> ProcessingConfig:
        """A copy with the given settings changed (``None`` values are ignored). Name a setting by its
        ``flight.toml`` key (``gnss_sigma=(1, 1, 3)``, ``method="graph"``), a whole section by its name
        (``gnss=GnssSection(...)``), and the tables ``pos_columns``, ``camera_columns`` and ``imu`` by their
        name with a ``dict``. Raises :class:`ConfigValueError` naming ``section.key`` for a bad value."""
        sections: dict[str, Any] = {}
        keys: dict[str, dict[str, Any]] = {}
        for name, value in changes.items():
            if value is None:
                continue
            if name in _MAP_SECTIONS and isinstance(value, dict):
                sections[name] = _SECTION_TYPES[name](value)
            elif name in _SECTION_TYPES:
                sections[name] = value
            elif name in _KEYS:
                section, attribute = _KEYS[name]
                keys.setdefault(section, {})[attribute] = value
            else:
                raise TypeError(f"unknown setting {name!r}; the flight.toml keys are {', '.join(sorted(_KEYS))}")
        for section, values in keys.items():
            sections[section] = replace(sections.get(section, getattr(self, section)), **values)
        return replace(self, **sections)


@dataclass(frozen=True)
class InsSettings:
    """What the full-state filters (:mod:`georef.fusion.ins`) read: the GNSS lever arm [m, body], the ``gnss``,
    ``gnss_gate``, ``unit``, ``ins``, ``imu`` and ``yaw_offset`` (heading fallback) sections."""

    lever_arm_gnss: tuple[float, float, float]
    gnss: GnssSection
    gnss_gate: GnssGateSection
    unit: UnitSection
    ins: InsSection
    imu: ImuSection
    yaw_offset: YawOffsetSection

    @classmethod
    def of(cls, cfg: ProcessingConfig, **extra: Any) -> InsSettings:
        """The sections of ``cfg`` these settings hold."""
        return cls(lever_arm_gnss=cfg.mounting.lever_arm_gnss, gnss=cfg.gnss, gnss_gate=cfg.gnss_gate, unit=cfg.unit,
                   ins=cfg.ins, imu=cfg.imu, yaw_offset=cfg.yaw_offset, **extra)

    def with_lever_arm(self, lever_arm_gnss: Any) -> InsSettings:
        """A copy with another GNSS lever arm [m, body] (three numbers)."""
        return replace(self, lever_arm_gnss=MountingSection(lever_arm_gnss=lever_arm_gnss).lever_arm_gnss)

    def imu_error_model(self) -> ImuErrorModel:
        """The datasheet error model: ``ins.imu_preset`` with the ``[imu]`` overrides."""
        return self.imu.error_model(self.ins.imu_preset)


@dataclass(frozen=True)
class GraphSettings(InsSettings):
    """What the factor graph (:mod:`georef.fusion.graph`) reads: the full-state filters' settings (it starts from
    their EKF + RTS), the ``graph`` section and the 1-sigma [m] of the given GNSS lever arm."""

    graph: GraphSection = field(default_factory=GraphSection)
    lever_arm_gnss_sigma: float | tuple[float, float, float] | None = None

    @classmethod
    def of(cls, cfg: ProcessingConfig, **extra: Any) -> GraphSettings:
        return super().of(cfg, graph=cfg.graph, lever_arm_gnss_sigma=cfg.mounting.lever_arm_gnss_sigma, **extra)


@dataclass(frozen=True)
class AxisSettings:
    """What the per-axis method (:mod:`georef.fusion.axis`) reads: the GNSS lever arm [m, body], the ``gnss``,
    ``gnss_gate``, ``unit`` (its angles' sigmas), ``yaw_offset`` and ``axis`` sections."""

    lever_arm_gnss: tuple[float, float, float]
    gnss: GnssSection
    gnss_gate: GnssGateSection
    unit: UnitSection
    yaw_offset: YawOffsetSection
    axis: AxisSection

    @classmethod
    def of(cls, cfg: ProcessingConfig) -> AxisSettings:
        """The sections of ``cfg`` these settings hold."""
        return cls(lever_arm_gnss=cfg.mounting.lever_arm_gnss, gnss=cfg.gnss, gnss_gate=cfg.gnss_gate, unit=cfg.unit,
                   yaw_offset=cfg.yaw_offset, axis=cfg.axis)


def _line_of(text: str, section: str, key: str | None) -> int | None:
    """1-based line of ``key`` inside ``[section]`` (of the section's header when ``key`` is None), if found."""
    current = None
    for number, line in enumerate(text.splitlines(), 1):
        header = re.match(r"\s*\[\s*([^\]\s]+)\s*\]", line)
        if header:
            current = header.group(1).strip("\"'")
            if key is None and current == section:
                return number
        elif current == section and key is not None and re.match(rf"\s*[\"']?{re.escape(key)}[\"']?\s*=", line):
            return number
    return None


def _error(path: Path, text: str, key: str, message: str) -> InputError:
    """An InputError at ``key`` (``section.key`` or ``section``), with its line when it can be found."""
    section, _, name = key.partition(".")
    return InputError(path, _line_of(text, section, name or None), key, message)


def load_config(path: Path | str, base: ProcessingConfig | None = None) -> ProcessingConfig:
    """Read a ``flight.toml`` over ``base`` (default: the defaults); unknown sections or keys and bad values are
    errors that name the file, the line and the ``section.key``."""
    path = Path(path)
    if not path.exists():
        raise InputError(path, None, None, "configuration file not found")
    text = path.read_text(encoding="utf-8")
    try:
        document = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        line = getattr(exc, "lineno", None)
        raise InputError(path, line, None, f"not valid TOML: {exc}") from None
    cfg = base or ProcessingConfig()
    sections: dict[str, Any] = {}
    try:
        for section, content in document.items():
            if section not in _SECTION_TYPES or not isinstance(content, dict):
                raise _error(path, text, section, f"unknown section [{section}]; known: {', '.join(_SECTION_TYPES)}")
            kind = _SECTION_TYPES[section]
            if section in _MAP_SECTIONS:
                sections[section] = kind(content)
                continue
            by_key = {_key(f): f.name for f in fields(kind)}
            values: dict[str, Any] = {}
            for key, value in content.items():
                if section == "ins" and key == "imu_noise_from_data":
                    raise _error(path, text, "ins.imu_noise_from_data", "this setting was removed: the noise model "
                                 "is now always fitted to the data (docs/method-ins.md); delete the line")
                if key not in by_key:
                    raise _error(path, text, f"{section}.{key}", f"unknown key; [{section}] takes "
                                 f"{', '.join(sorted(by_key))}")
                if key == "image_names" and isinstance(value, str) and "{" not in value \
                        and not Path(value).is_absolute():
                    value = str(path.parent / value)  # a name table beside flight.toml, wherever georef runs
                values[by_key[key]] = tuple(value) if isinstance(value, list) else value
            sections[section] = replace(getattr(cfg, section), **values)
    except ConfigValueError as exc:
        raise _error(path, text, exc.key, str(exc)) from None
    return replace(cfg, **sections)


def configured_keys(paths: list[Path] | list[str] | Path | str | None) -> set[str]:
    """The flight.toml keys the files ``paths`` set (the files are read by :func:`load_configs` first, which
    locates every error)."""
    if paths is None:
        return set()
    keys: set[str] = set()
    for path in [paths] if isinstance(paths, str | Path) else paths:
        document = tomllib.loads(Path(path).read_text(encoding="utf-8"))
        for content in document.values():
            if isinstance(content, dict):
                keys.update(content)
    return keys


def load_configs(paths: list[Path] | list[str] | Path | str | None) -> ProcessingConfig:
    """Read ``flight.toml`` files in order, each later one changing only the keys it names (``None`` or an empty
    list: the defaults)."""
    if paths is None:
        return ProcessingConfig()
    cfg = ProcessingConfig()
    for path in [paths] if isinstance(paths, (str, Path)) else paths:
        cfg = load_config(path, base=cfg)
    return cfg


def _number(value: float) -> str:
    """A float as TOML: the short ``g`` form when it reads back exactly, else every digit needed."""
    short = f"{value:g}"
    return short if float(short) == value else repr(value)


def config_to_toml(cfg: ProcessingConfig) -> str:
    """The configuration as a ``flight.toml`` document (every key of the scalar sections that has a value, and
    the non-empty tables); :func:`load_config` reads it back to an equal configuration."""

    def fmt(value: Any) -> str:
        if isinstance(value, tuple):
            return "[" + ", ".join(_number(v) for v in value) + "]"
        if isinstance(value, str):
            return json.dumps(value, ensure_ascii=False)
        if isinstance(value, bool):
            return "true" if value else "false"
        return _number(value) if isinstance(value, float) else str(value)

    blocks: dict[str, list[str]] = {}
    for section, key, value in cfg.items():
        if section in _MAP_SECTIONS:
            blocks[section] = [f"{k} = {fmt(v)}" for k, v in value.items()]
        elif value is not None:
            blocks.setdefault(section, []).append(f"{key} = {fmt(value)}")
    return "\n\n".join(f"[{section}]\n" + "\n".join(rows) for section, rows in blocks.items() if rows) + "\n"
