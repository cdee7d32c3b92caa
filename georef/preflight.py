"""Every option of ``georef process``, ``fuse`` and ``batch`` checked before any file is processed:
:func:`preflight` takes the command's request and gives its plan, or refuses the request with one error.

What is checked, in the order the commands have always reported it: which inputs go together (a log's first bytes
are read to tell its format), the configuration files with the options over them, the outputs (their formats, at
most one on standard output, a target that can be written), the output CRS, its geoid grid and the image names,
and the hand-offs (SBETs: a date; geotagged image copies: their folder). The refusals are
:class:`georef.option_values.OptionError` naming the option, or the readers' own errors (a configuration file's
line, an unknown CRS). The output CRS and the image names are checked here once; the plan hands them to the
pipeline (:class:`OutputChecks`), which checks them itself only when called without one. The inputs' checks are
:mod:`georef.preflight_inputs`, the hand-offs' (SBETs, image copies) :mod:`georef.preflight_handoffs`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

from georef.config import ConfigValueError, ProcessingConfig, configured_keys, load_configs
from georef.io.image_names import ImageNames
from georef.option_values import OptionError, is_stdout, triple
from georef.preflight_handoffs import check_image_request, check_sbet_request, fuse_sbet_specs
from georef.preflight_inputs import InputSource, ProcessInputs, bag_or_files, check_time_scale, input_source

if TYPE_CHECKING:
    from georef.frames.heights import OutputFrames
    from georef.io.exports import ExportSpec
    from georef.pipeline import ProcessResult

__all__ = ["BatchPlan", "BatchRequest", "FusePlan", "FuseRequest", "InputSource", "OptionValue", "OutputChecks",
           "ProcessInputs", "ProcessPlan", "ProcessRequest", "configured", "image_names", "input_source",
           "output_checks", "output_frames", "preflight"]


class OptionValue(NamedTuple):
    """A flight.toml setting given on the command line: the ``option`` that gave it and its ``value``; with a
    ``unit``, the value is the option's text of three numbers in that unit (e.g. "0.5,0,-1.2", metres)."""

    option: str
    value: Any
    unit: str | None = None


class OutputChecks(NamedTuple):
    """The output CRS and heights (None: WGS 84 ellipsoidal, no projection) and the image names, checked."""

    frames: OutputFrames | None
    image_names: ImageNames | None


def output_frames(cfg: ProcessingConfig) -> OutputFrames | None:
    """The output CRS and heights, checked (grid installed, CRS known) before any input is read."""
    if cfg.output.crs or cfg.output.height != "ellipsoidal":
        from georef.frames.heights import OutputFrames  # pyproj only when a CRS or a geoid is asked for

        return OutputFrames(cfg.output.crs, cfg.output.height, cfg.output.vertical_crs)
    return None


def image_names(cfg: ProcessingConfig) -> ImageNames | None:
    """The image names of ``cfg`` (a pattern or a CSV of frame,name), checked; None without them."""
    return ImageNames.parse(cfg.output.image_names) if cfg.output.image_names else None


def output_checks(cfg: ProcessingConfig) -> OutputChecks:
    """:func:`output_frames` and :func:`image_names` of ``cfg``."""
    return OutputChecks(output_frames(cfg), image_names(cfg))


def configured(configs: list[Path] | None, options: Mapping[str, OptionValue]) -> ProcessingConfig:
    """The configuration files ``configs`` read in order, with ``options`` (flight.toml key -> option; a None
    value is not given) over them; a value its section refuses is reported against the option that gave it."""
    cfg = load_configs(configs)
    values = {key: (given.option, triple(given.value, given.option, given.unit) if given.unit else given.value)
              for key, given in options.items()}
    try:
        return cfg.updated(**{key: value for key, (_, value) in values.items()})
    except ConfigValueError as exc:
        key = exc.key.rsplit(".", 1)[-1]
        option, value = values.get(key, (None, None))
        if option is None or value is None:
            raise
        raise OptionError(f"{option}: {str(exc).removeprefix(exc.key + ' ')}") from None


def one_stdout(paths: Mapping[str, Path | None]) -> None:
    """Refuse two outputs (option -> path) on standard output before anything runs."""
    named = [name for name, path in paths.items() if is_stdout(path)]
    if len(named) > 1:
        raise OptionError(f"only one output can go to standard output ('-'), got {' and '.join(named)}")


def not_stdout(path: Path | None, option: str, why: str) -> None:
    """Refuse ``-`` for ``option``, which cannot go to standard output (``why``)."""
    if is_stdout(path):
        raise OptionError(f"{option} cannot be '-' (standard output): {why}")


@dataclass(frozen=True)
class ProcessRequest:
    """What ``georef process`` was given: its inputs, configuration files and options over them (flight.toml key
    -> :class:`OptionValue`), the EO table ``output`` (None: eo.csv) in ``output_format``, the ``exports``
    (FORMAT:FILE, images:DIR, sbet:FILE), the ``report`` and ``summary_json`` files, the photos for the image
    copies with the camera clock offset [s], and the SBETs' ``utc_date`` and ``sbet_rate`` [Hz]."""

    inputs: ProcessInputs
    configs: list[Path] | None = None
    options: Mapping[str, OptionValue] = field(default_factory=dict)
    output: Path | None = None
    output_format: str | None = None
    exports: list[str] = field(default_factory=list)
    report: Path | None = None
    summary_json: Path | None = None
    images: Path | None = None
    camera_clock_offset: float | None = None
    utc_date: str | None = None
    sbet_rate: float | None = None


@dataclass(frozen=True)
class ProcessPlan:
    """A checked ``georef process`` request: its ``source``, configuration ``cfg``, the outputs ``specs`` (the EO
    table first, then each export), the folders of the image copies, the checked CRS and image names, and the
    flight.toml keys the user set (``given``: an autopilot log's defaults stand for the others)."""

    source: InputSource
    cfg: ProcessingConfig
    specs: list[ExportSpec]
    image_targets: list[Path]
    checked: OutputChecks
    given: set[str]

    @property
    def sbet_specs(self) -> list[ExportSpec]:
        return [spec for spec in self.specs if spec.fmt == "sbet"]

    def run(self, progress: Callable[[str], None]) -> ProcessResult:
        """Read, fuse and georeference (``progress(step)`` names each stage)."""
        return self.source.run(self.cfg, progress, self.given, self.checked)


def _process_specs(request: ProcessRequest) -> tuple[list[ExportSpec], list[Path]]:
    """The EO table and the exports asked for (checked: formats, names, at most one on standard output), and
    the folders of the image copies."""
    from georef.io.exports import ExportError, ExportSpec, format_of, parse_export

    output, output_format = request.output, request.output_format
    if output is None:
        if output_format not in (None, "csv"):
            raise OptionError(f"--format {output_format} needs -o FILE (eo.csv is the EO table's default); or add "
                              f"--export {output_format}:FILE to write it beside eo.csv")
        output = Path("eo.csv")
    if output_format is None:
        try:
            output_format = format_of(output)
        except ExportError:
            output_format = "csv"
    # --export images:DIR is a folder of photo copies, not a file of the EO table (georef/io/image_export.py)
    if "images" in request.exports:
        raise OptionError("--export images:DIR: name the folder for the geotagged copies of --images")
    image_targets = [Path(text.partition(":")[2]) for text in request.exports if text.startswith("images:")]
    exports = [text for text in request.exports if not text.startswith("images:")]
    specs = [ExportSpec(format_of(output, output_format), output), *(parse_export(text) for text in exports)]
    one_stdout({"-o": output, "--summary-json": request.summary_json,
                **{f"--export {text}": spec.path for text, spec in zip(exports, specs[1:], strict=True)}})
    return specs, image_targets


def _process_plan(request: ProcessRequest) -> ProcessPlan:
    from georef.io.atomic import resolve_target
    from georef.io.exports import check_exports

    one_stdout({"-o": request.output, "--summary-json": request.summary_json})
    not_stdout(request.report, "--report", "the report is written atomically as a file")
    source = input_source(request.inputs)
    cfg = configured(request.configs, request.options)
    specs, image_targets = _process_specs(request)
    frames = output_frames(cfg)
    check_exports(specs, frames)
    check_image_request(request.images, image_targets, request.camera_clock_offset, frames, cfg.output.image_names)
    if specs[0].fmt == "sbet":
        raise OptionError("an SBET is the trajectory, not the EO table: write it with --export sbet:FILE")
    # an autopilot log dates itself; a bag or imu.csv may (Unix stamps, a .pos): checked once read
    check_sbet_request([spec for spec in specs if spec.fmt == "sbet"], request.utc_date, request.sbet_rate,
                       dated=bool({"log", "bag", "imu"} & source.files.keys()))
    names = image_names(cfg)
    for target in (*(spec.path for spec in specs), request.report):  # a device, a directory or a write-protected
        if target is not None and not is_stdout(target):             # file: refused before processing
            resolve_target(target)
    given = configured_keys(request.configs) | {key for key in ("lever_arm_gnss", "imu_preset")
                                                if key in request.options and request.options[key].value is not None}
    return ProcessPlan(source, cfg, specs, image_targets, OutputChecks(frames, names), given)


@dataclass(frozen=True)
class FuseRequest:
    """What ``georef fuse`` was given: imu.csv and gnss.csv or a bag (with its topics), the ``time_scale`` of a
    .pos, the trajectory ``output``, the configuration with options over it, the ``exports`` (sbet:FILE only) with
    their ``utc_date`` and ``sbet_rate`` [Hz], and the ``summary_json`` file."""

    imu: Path | None = None
    gnss: Path | None = None
    bag: Path | None = None
    imu_topic: str | None = None
    gnss_topic: str | None = None
    time_scale: str = "auto"
    output: Path = Path("traj.csv")
    configs: list[Path] | None = None
    options: Mapping[str, OptionValue] = field(default_factory=dict)
    exports: list[str] = field(default_factory=list)
    sbet_rate: float | None = None
    utc_date: str | None = None
    summary_json: Path | None = None


@dataclass(frozen=True)
class FusePlan:
    """A checked ``georef fuse`` request: its configuration and the SBETs to write."""

    cfg: ProcessingConfig
    sbet_specs: list[ExportSpec]


def _fuse_plan(request: FuseRequest) -> FusePlan:
    bag_or_files(request.bag, request.imu_topic, request.gnss_topic, {"--imu": request.imu, "--gnss": request.gnss})
    check_time_scale(request.time_scale, {"--gnss": request.gnss})
    one_stdout({"-o": request.output, "--summary-json": request.summary_json})
    sbet_specs = fuse_sbet_specs(request.exports, request.output)
    check_sbet_request(sbet_specs, request.utc_date, request.sbet_rate, dated=True)  # checked once the IMU is read
    return FusePlan(configured(request.configs, request.options), sbet_specs)


@dataclass(frozen=True)
class BatchRequest:
    """What ``georef batch`` was given: the ``output`` folder, the ``exports`` of every flight (FORMAT[:NAME],
    images[:NAME]), the ``method`` over every flight's (None: each flight's) and ``shared_calibration``."""

    output: Path
    exports: list[str] = field(default_factory=list)
    method: str | None = None
    shared_calibration: bool = False


@dataclass(frozen=True)
class BatchPlan:
    """A checked ``georef batch`` request: each flight's exports as (format, file name in its folder)."""

    exports: tuple[tuple[str, str], ...]


def _batch_plan(request: BatchRequest) -> BatchPlan:
    from georef.io.exports import parse_folder_export

    not_stdout(request.output, "-o", "batch writes a folder of files")
    # images[:NAME]: geotagged copies of each flight's photos (<flight>/images/) in <out>/<flight>/NAME (images)
    images = tuple(("images", text.partition(":")[2] or "images") for text in request.exports
                   if text == "images" or text.startswith("images:"))
    for _, name in images:
        if Path(name).name != name or name in (".", ".."):
            raise OptionError(f"--export images:{name}: give a plain folder name; each flight's copies go in its "
                              "own folder")
    specs = [parse_folder_export(text) for text in request.exports  # checked before any flight runs
             if not (text == "images" or text.startswith("images:"))]
    if request.shared_calibration and request.method != "graph":
        raise OptionError("needs --method graph (the calibration is a variable of the factor graph)",
                          option="--shared-calibration")
    return BatchPlan(tuple((spec.fmt, str(spec.path)) for spec in specs) + images)


def preflight(request: ProcessRequest | FuseRequest | BatchRequest) -> ProcessPlan | FusePlan | BatchPlan:
    """Check every option of a ``process``, ``fuse`` or ``batch`` request before any file is processed (a log's
    first bytes aside, read to tell its format); its plan, or :class:`OptionError` (or a reader's error) for
    the first thing wrong."""
    if isinstance(request, ProcessRequest):
        return _process_plan(request)
    if isinstance(request, FuseRequest):
        return _fuse_plan(request)
    return _batch_plan(request)
