"""``georef attitude``: roll, pitch (and yaw) from raw gyro, accelerometer and magnetometer data
(:func:`georef.attitude.run.estimate_attitude`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape

from ..options import AttitudeMethod, Quiet, output_option, plain
from ..output import write_target
from ..running import messages
from ..terminal import target_text


def attitude(
    imu: Annotated[Path, typer.Option(help="imu.csv: time [s], gyro_x..z [rad/s], acc_x..z [m/s^2], optional "
                                           "mag_x..z (any unit); body axes forward-right-down.")],
    method: AttitudeMethod = "mekf",
    output: Annotated[Path, output_option("Attitude table to write (CSV, degrees).")] = Path("attitude.csv"),
    inclination: Annotated[float, typer.Option(help="Magnetic inclination in degrees (field reference "
                                                    "[cos I, 0, sin I] in NED).")] = 60.0,
    gain: Annotated[float, typer.Option(help="Complementary filter: accelerometer weight per sample (0-1).")] = 0.02,
    gyro_noise: Annotated[float, typer.Option(help="Gyro white noise per sample in rad/s (mekf, ukf).")] = 0.01,
    accel_sigma: Annotated[float, typer.Option(help="Noise of the normalised gravity direction (unitless, "
                                                    "~ radians); also the kf's angle sigma.")] = 0.01,
    alpha: Annotated[float, typer.Option(help="UKF sigma-point spread alpha.")] = 0.01,
    beta: Annotated[float, typer.Option(help="UKF prior-knowledge beta (2 for Gaussian).")] = 2.0,
    kappa: Annotated[float, typer.Option(help="UKF secondary scaling kappa.")] = 0.0,
    quiet: Quiet = False,
) -> None:
    """Roll, pitch (and yaw with mekf/ukf) from raw gyro, accelerometer and optional magnetometer data."""
    from georef.attitude.run import estimate_attitude
    from georef.io.atomic import atomic_write
    from georef.io.generic import read_marg_csv

    method = plain(method)
    time_s, gyro, accel, mag, _ = read_marg_csv(imu)
    table = estimate_attitude(method, time_s, gyro, accel, mag, inclination_deg=inclination, gain=gain,
                              gyro_noise=gyro_noise, accel_sigma=accel_sigma, alpha=alpha, beta=beta, kappa=kappa)
    def write(path: Path) -> None:
        with atomic_write(path) as handle:
            table.to_csv(handle, index=False, float_format="%.8g", lineterminator="\n")

    write_target(output, write)
    if not quiet:
        messages(output).print(f"{len(table)} samples -> {target_text(output)} ({escape(method)}"
                                f"{', magnetometer' if mag is not None else ''})", highlight=False,
                                soft_wrap=True)
