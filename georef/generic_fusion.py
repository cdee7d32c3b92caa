"""``georef fuse``'s library side: generic IMU and GNSS (imu.csv with gnss.csv or an RTKLIB/Emlid .pos, or a ROS
bag's sensor_msgs/Imu and NavSatFix topics) read into the filters' inputs (:func:`read_fuse_inputs`) and fused
into a trajectory with a method (:func:`fuse`): rts, ekf or graph."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from georef.config import GraphSettings, InsSettings

if TYPE_CHECKING:
    from georef.config import ProcessingConfig
    from georef.fusion.ins import InsInputs
    from georef.fusion.solution import NavSolution


@dataclass(frozen=True)
class FuseInputs:
    """The filters' inputs (``ins``: time [s], gyro [rad/s], accel [m/s^2] in the body frame, the GNSS fixes and
    the heading sources), what they were read from (``kind`` for the QC, ``files`` for the summary: option or
    topic -> value), and the reader that read a bag (None for imu.csv)."""

    ins: InsInputs
    kind: str
    files: dict[str, Any]
    from_pos: bool = False
    bag_read: Any = None

    def reader_notices(self) -> list[Any]:
        """What the bag reader or the .pos reader converted, floored or dropped (a .pos's time scale aside: it is
        reported on its own)."""
        if self.bag_read is not None:
            return list(self.bag_read.all_notices)
        if self.from_pos:
            from georef.io.pos_time_scale import TimeScaleNotice

            return [notice for notice in self.ins.gnss.notices if not isinstance(notice, TimeScaleNotice)]
        return []


def read_fuse_inputs(imu: Path | None, gnss: Path | None, bag: Path | None, imu_topic: str | None,
                     gnss_topic: str | None, time_scale: str = "auto") -> FuseInputs:
    """Read ``bag`` (its IMU and GNSS topics, default the only ones), else ``imu`` (imu.csv) and ``gnss`` (gnss.csv,
    or a .pos put on imu.csv's ``time_scale``: :data:`georef.io.pos_time_scale.CHOICES`)."""
    from georef.fusion.ins import InsInputs

    if bag is not None:
        from georef.io.rosbag import read_bag

        read = read_bag(bag, imu_topic, gnss_topic)
        inputs = InsInputs(time=read.time, gyro=read.gyro, accel=read.accel, gnss=read.gnss, source=str(bag))
        return FuseInputs(inputs, read.kind, {"bag": bag, "imu_topic": read.imu_topic, "gnss_topic": read.gnss_topic},
                          bag_read=read)
    from georef.io.generic import read_imu_csv, read_imu_heading_sources
    from georef.io.pos_time_scale import is_solution_file, read_gnss_on_imu_scale

    time_s, gyro, accel, _ = read_imu_csv(imu)
    mag, autopilot_yaw = read_imu_heading_sources(imu)
    fixes = read_gnss_on_imu_scale(gnss, time_s, time_scale, imu.name)
    from_pos = is_solution_file(gnss)
    inputs = InsInputs(time=time_s, gyro=gyro, accel=accel, gnss=fixes, source=str(imu), mag=mag,
                       autopilot_yaw=autopilot_yaw)
    return FuseInputs(inputs, "imu.csv + RTKLIB .pos" if from_pos else "imu.csv + gnss.csv",
                      {"imu": imu, "gnss": gnss}, from_pos=from_pos)


def fuse(inputs: FuseInputs, cfg: ProcessingConfig, method: str) -> NavSolution:
    """The trajectory of ``inputs`` with ``method``: rts (EKF + RTS smoother), ekf (the forward filter) or graph
    (the factor-graph smoother, with the config's [graph] section)."""
    if method == "graph":
        from georef.fusion.graph import solve_graph_inputs

        return solve_graph_inputs(inputs.ins, GraphSettings.of(cfg))
    from georef.fusion.ins import solve_ins

    return solve_ins(inputs.ins, InsSettings.of(cfg), smooth=method == "rts")
