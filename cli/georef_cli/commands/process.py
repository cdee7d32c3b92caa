"""``georef process``: the exterior orientation of every frame (its options; the run is
:mod:`georef_cli.process_run`)."""

from __future__ import annotations

from ..options import (
    AttitudeSource,
    BagFile,
    Boresight,
    CameraArgument,
    CameraClockOffset,
    CameraLeverArm,
    CameraTimeOffset,
    CameraTimeSigma,
    CameraUtcOffset,
    ConfigFile,
    Crs,
    EoOutput,
    EventsFile,
    GnssFile,
    GnssLatency,
    GnssLeverArm,
    GnssRate,
    GnssSigma,
    GnssTopic,
    Height,
    ImageNamesOption,
    ImagesFolder,
    ImuFile,
    ImuInstance,
    ImuPreset,
    ImuTopic,
    MagneticDeclination,
    OutputFormat,
    PosArgument,
    ProcessExport,
    ProcessMethod,
    Quiet,
    Report,
    SbetRate,
    SummaryJson,
    TimeScale,
    UtcDate,
    Vehicle,
    Verbose,
    plain,
    settings_given,
)

#: the flight.toml settings process's options give: key -> (option, parameter[, unit of its three numbers])
SETTINGS = {
    "method": ("--method", "method"), "imu_preset": ("--imu-preset", "imu_preset"),
    "lever_arm_gnss": ("--gnss-lever-arm", "gnss_lever_arm", "metres"),
    "lever_arm_camera": ("--camera-lever-arm", "camera_lever_arm", "metres"),
    "boresight": ("--boresight", "boresight", "degrees"), "gnss_sigma": ("--gnss-sigma", "gnss_sigma", "metres"),
    "gnss_rate_hz": ("--gnss-rate", "gnss_rate"), "camera_utc_offset": ("--camera-utc-offset", "camera_utc_offset"),
    "crs": ("--crs", "crs"), "attitude_source": ("--attitude-source", "attitude_source"),
    "camera_time_offset": ("--camera-time-offset", "camera_time_offset"),
    "camera_time_sigma": ("--camera-time-sigma", "camera_time_sigma"),
    "gnss_latency": ("--gnss-latency", "gnss_latency"), "vehicle": ("--vehicle", "vehicle"),
    "magnetic_declination": ("--magnetic-declination", "magnetic_declination"), "height": ("--height", "height"),
    "image_names": ("--image-names", "image_names"),
}


def process(
    pos: PosArgument = None,
    camera: CameraArgument = None,
    imu: ImuFile = None,
    gnss: GnssFile = None,
    events: EventsFile = None,
    imu_instance: ImuInstance = None,
    bag: BagFile = None,
    imu_topic: ImuTopic = None,
    gnss_topic: GnssTopic = None,
    time_scale: TimeScale = "auto",
    imu_preset: ImuPreset = None,
    output: EoOutput = None,
    output_format: OutputFormat = None,
    export: ProcessExport = None,
    sbet_rate: SbetRate = None,
    utc_date: UtcDate = None,
    images: ImagesFolder = None,
    camera_clock_offset: CameraClockOffset = None,
    height: Height = None,
    image_names: ImageNamesOption = None,
    config: ConfigFile = None,
    method: ProcessMethod = None,
    gnss_lever_arm: GnssLeverArm = None,
    camera_lever_arm: CameraLeverArm = None,
    boresight: Boresight = None,
    gnss_sigma: GnssSigma = None,
    gnss_rate: GnssRate = None,
    camera_utc_offset: CameraUtcOffset = None,
    camera_time_offset: CameraTimeOffset = None,
    camera_time_sigma: CameraTimeSigma = None,
    gnss_latency: GnssLatency = None,
    vehicle: Vehicle = None,
    magnetic_declination: MagneticDeclination = None,
    crs: Crs = None,
    attitude_source: AttitudeSource = None,
    report: Report = None,
    quiet: Quiet = False,
    verbose: Verbose = False,
    summary_json: SummaryJson = None,
) -> None:
    """The exterior orientation of every frame: from an autopilot log and its camera events, from POS.txt and
    Kamera.txt, from imu.csv, gnss.csv and events.csv, or from a ROS bag and events.csv.

    Exit code 4: the outputs are written but the quality checks failed (docs/qc.md).
    """
    settings = settings_given(SETTINGS, locals())
    from georef.pipeline import preflight
    from georef.preflight import ProcessInputs, ProcessRequest

    from ..process_run import run_process

    inputs = ProcessInputs(pos, camera, imu, gnss, events, imu_instance, bag, imu_topic, gnss_topic,
                           plain(time_scale))
    request = ProcessRequest(inputs, config, settings, output, output_format, export or [], report, summary_json,
                             images, camera_clock_offset, utc_date, sbet_rate)
    run_process(preflight(request), request, quiet=quiet, verbose=verbose)
