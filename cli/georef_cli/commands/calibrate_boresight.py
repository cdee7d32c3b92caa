"""``georef calibrate-boresight``: the camera boresight and lever arm from a block adjusted with ground control
(the estimate: :mod:`georef_cli.calibrate`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape

from ..options import ConfigFile, Quiet, SummaryJson, georef_version, output_option
from ..output import write_json
from ..running import EXIT_QC_FAILED, console, messages


def calibrate_boresight(
    eo: Annotated[Path, typer.Argument(help="The EO table georef process wrote (eo.csv; with an image column, "
                                            "--image-names), processed with the mounting of --config / "
                                            "--boresight / --camera-lever-arm.")],
    adjusted: Annotated[Path, typer.Argument(help="The block's adjusted cameras (bundle adjustment with ground "
                                                  "control): a Metashape camera export (CSV with X, Y, Z [m] and "
                                                  "Omega, Phi, Kappa [deg]; the _est columns when present), Pix4D's "
                                                  "calibrated_external_camera_parameters.txt or ODM's "
                                                  "odm_report/shots.geojson.")],
    crs: Annotated[str, typer.Option(help="Projected CRS the block was adjusted in (its X, Y in metres), e.g. "
                                          "EPSG:32633; the photos' ω, φ, κ refer to its grid north.")],
    adjusted_format: Annotated[str | None, typer.Option(
        "--format", help="metashape, pix4d or odm (default: odm for .geojson/.json, pix4d for "
                         "*calibrated_external*, else metashape).")] = None,
    config: ConfigFile = None,
    boresight: Annotated[str | None, typer.Option(
        help="The boresight roll,pitch,yaw [deg] the EO was processed with (default: --config's).")] = None,
    camera_lever_arm: Annotated[str | None, typer.Option(
        help="The camera lever arm x,y,z [m, body: x forward, y right, z down] the EO was processed with "
             "(default: --config's).")] = None,
    ellipsoidal: Annotated[bool, typer.Option(
        "--ellipsoidal-heights", help="Compare the block's heights with the EO's ellipsoidal height even when the "
                                      "EO has height_orthometric (only the not-estimated vertical terms change).")
    ] = False,
    process_summary: Annotated[Path | None, typer.Option(
        help="The --summary-json of the georef process run that wrote the EO table: its accelerometer-bias sigma "
             "[m/s^2] over g is the sigma of the INS tilt fixed in the body frame in the roll and pitch sigmas "
             "[deg]. Without it those sigmas are conservative (bounded by the EO's tilt sigma).")] = None,
    output: Annotated[Path, output_option("calibration.toml to write: [mounting] boresight [deg] and "
                                          "lever_arm_camera [m] for georef process --config.", stdout=False)
                      ] = Path("calibration.toml"),
    quiet: Quiet = False,
    summary_json: SummaryJson = None,
) -> None:
    """Calibrate the camera boresight [deg] and lever arm [m] from a block adjusted with ground control.

    Per photo the EO's camera attitude and position are compared with the adjusted ones; strips (straight runs)
    give the estimate, its sigma includes the INS's flight-constant yaw error and its body-fixed tilt (the
    accelerometer-bias sigma of --process-summary over g; without it a conservative bound), and a jackknife over
    strips checks it. The lever arm's x (trigger latency) and z (vertical datum) are reported, not applied; y is
    applied only with strips in opposite headings and when over twice its sigma. Exit code 0: written; 2: bad
    input, no matching names, too few photos or strips; 4: written but weak or inconsistent (fewer than 3 strips,
    one heading, a failed chi-square or jackknife check).
    """
    from georef.preflight import OptionValue, configured, not_stdout

    from ..calibrate import print_result, run

    not_stdout(output, "-o", "calibrate-boresight writes calibration.toml")
    cfg = configured(config, {"boresight": OptionValue("--boresight", boresight, "deg"),
                              "lever_arm_camera": OptionValue("--camera-lever-arm", camera_lever_arm, "m")})
    result = run(eo, adjusted, adjusted_format, crs, cfg.mounting.boresight, cfg.mounting.lever_arm_camera, output,
                 ellipsoidal, process_summary)
    code = EXIT_QC_FAILED if result.weak else 0
    if summary_json is not None:
        from ..summary import SCHEMA_VERSION

        inputs = {"eo": str(eo), "adjusted": str(adjusted), "config": [str(p) for p in config or []], "crs": crs,
                  "process_summary": None if process_summary is None else str(process_summary)}
        write_json(summary_json, {"schema": SCHEMA_VERSION, "georef_version": georef_version(),
                                  "command": "calibrate-boresight", "exit_code": code, "inputs": inputs,
                                  "outputs": [{"what": "calibration config", "format": "toml", "path": str(output)}],
                                  "figures": result.summary()})
    if not quiet:
        print_result(result, output, messages(summary_json), console)
    elif result.weak:
        for problem in result.problems:
            console.print(f"[bold red]weak:[/] {escape(problem)}", highlight=False)
    if code:
        raise typer.Exit(code=code)
