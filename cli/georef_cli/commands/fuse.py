"""``georef fuse``: generic IMU and GNSS files, or a ROS bag's topics, fused into a trajectory (the inputs read and
fused by :mod:`georef.generic_fusion`; the options checked by :func:`georef.pipeline.preflight`)."""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Annotated

import typer

from ..fuse_run import finish_fuse
from ..handoffs import sbet_clock, write_fuse_outputs
from ..options import (
    BagFile,
    ConfigFile,
    FuseMethod,
    GnssLatency,
    GnssLeverArm,
    GnssSigma,
    GnssTopic,
    ImuPreset,
    ImuTopic,
    MagneticDeclination,
    Quiet,
    SbetRate,
    SummaryJson,
    TimeScale,
    UtcDate,
    Vehicle,
    output_option,
    plain,
    settings_given,
)
from ..running import stage_progress

#: the flight.toml settings fuse's options give: key -> (option, parameter[, unit of its three numbers])
SETTINGS = {
    "lever_arm_gnss": ("--gnss-lever-arm", "gnss_lever_arm", "metres"),
    "gnss_sigma": ("--gnss-sigma", "gnss_sigma", "metres"), "imu_preset": ("--imu-preset", "imu_preset"),
    "gnss_latency": ("--gnss-latency", "gnss_latency"), "vehicle": ("--vehicle", "vehicle"),
    "magnetic_declination": ("--magnetic-declination", "magnetic_declination"),
}


def fuse(
    imu: Annotated[Path | None, typer.Option(help="imu.csv: time [s], gyro_x..z [rad/s], acc_x..z [m/s^2], body "
                                                  "FRD (or --bag).")] = None,
    gnss: Annotated[Path | None, typer.Option(help="gnss.csv: time [s], lat, lon [deg], height [m] of the antenna, "
                                                   "optional sigma_n, sigma_e, sigma_u [m] (or --bag); or an RTKLIB/"
                                                   "Emlid .pos solution (recognised by its header; its times put on "
                                                   "imu.csv's scale, see --time-scale).")] = None,
    bag: BagFile = None,
    imu_topic: ImuTopic = None,
    gnss_topic: GnssTopic = None,
    time_scale: TimeScale = "auto",
    output: Annotated[Path, output_option("Trajectory to write (traj.csv).")] = Path("traj.csv"),
    config: ConfigFile = None,
    method: FuseMethod = "rts",
    gnss_lever_arm: GnssLeverArm = None,
    gnss_sigma: GnssSigma = None,
    imu_preset: ImuPreset = None,
    gnss_latency: GnssLatency = None,
    vehicle: Vehicle = None,
    magnetic_declination: MagneticDeclination = None,
    export: Annotated[list[str] | None, typer.Option(
        "--export", help="Also write sbet:FILE, the trajectory as an Applanix SBET with its smrmsg_<name>.out "
                         "(docs/sbet.md). The date: a .pos's, or Unix stamps' (a bag's), else imu.csv's times are "
                         "UTC seconds of --utc-date.")] = None,
    sbet_rate: SbetRate = None,
    utc_date: UtcDate = None,
    quiet: Quiet = False,
    summary_json: SummaryJson = None,
) -> None:
    """Fuse generic IMU and GNSS files (or a ROS bag's IMU and GNSS topics) into a trajectory (position,
    velocity, attitude with sigmas).

    Exit code 4: the trajectory is written but the quality checks failed (docs/qc.md).
    """
    settings = settings_given(SETTINGS, locals())
    from georef.generic_fusion import fuse as fuse_inputs
    from georef.generic_fusion import read_fuse_inputs
    from georef.pipeline import preflight
    from georef.preflight import FuseRequest

    time_scale, method = plain(time_scale), plain(method)
    request = FuseRequest(imu, gnss, bag, imu_topic, gnss_topic, time_scale, output, config, settings, export or [],
                          sbet_rate, utc_date, summary_json)
    plan = preflight(request)
    progress, step = stage_progress(quiet, total=3)
    with progress if progress is not None else contextlib.nullcontext():
        step("reading inputs")
        inputs = read_fuse_inputs(imu, gnss, bag, imu_topic, gnss_topic, time_scale)
        # the SBET's time scale and date, before the fusion's minutes: refused here, nothing written
        sbet_time = sbet_clock(inputs.ins.time, utc_date, {"--gnss": gnss}, time_scale, bag=bag is not None,
                               imu_label="the bag's IMU" if bag is not None else imu.name) if plan.sbet_specs else None
        step(f"fusing ({method})")
        nav = fuse_inputs(inputs, plan.cfg, method)
        step("writing trajectory")
        sbets = write_fuse_outputs(nav, inputs.ins.gyro, inputs.ins.accel, output, plan.sbet_specs, sbet_rate,
                                   sbet_time)
    finish_fuse(request, plan.cfg, method, inputs, nav, sbets, quiet)

