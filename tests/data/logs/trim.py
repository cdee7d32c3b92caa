"""How the real logs here were trimmed from their sources (README.md names them): run with the source files'
paths; it writes the trimmed files beside this script. Not used by the tests, which read the files it wrote.

    python tests/data/logs/trim.py ARDUPILOT_LOG171_BIN PX4_CORRUPT_ULG PX4_ESC_STATUS_ULG

* ArduPilot ``log171.bin``: the messages georef reads or compares (FMT, PARM, MSG, MODE, EV, IMU, IMU2, GPS, UBX3,
  ATT, AHR2, MAG) up to 222 s after the first IMU message, before the crash that ends the flight; gzipped.
* PX4 logs: the topics georef reads or compares, rewritten with pyulog's writer.
"""

from __future__ import annotations

import gzip
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ARDUPILOT_KEEP = ("FMT", "PARM", "MSG", "MODE", "EV", "IMU", "IMU2", "GPS", "UBX3", "ATT", "AHR2", "MAG")
ARDUPILOT_CUT_S = 222.0
PX4_TOPICS = ["sensor_combined", "vehicle_gps_position", "vehicle_attitude", "vehicle_magnetometer",
              "estimator_attitude", "camera_capture", "camera_trigger", "vehicle_imu"]


def trim_dataflash(source: Path, target: Path) -> None:
    from georef.aot import load as load_kernel
    from georef.io.logs.dataflash import read_binary

    data = source.read_bytes()
    buffer = np.frombuffer(data, dtype=np.uint8)
    lengths = np.zeros(256, dtype=np.int64)
    lengths[128] = 89
    offsets, types, _, _ = load_kernel("dataflash").scan(buffer, lengths, len(buffer))
    log = read_binary(source, data, ARDUPILOT_KEEP)
    by_id = {fmt.type_id: fmt.name for fmt in log.formats.values()}
    imu = log.messages["IMU"]
    boot = imu.columns["TimeUS"] * 1e-6 if imu.has("TimeUS") else imu.columns["TimeMS"] * 1e-3
    cut = boot[0] + ARDUPILOT_CUT_S
    # the boot time of every timed message kept; untimed ones (FMT, PARM, MSG) stay
    late = set()
    for name in ARDUPILOT_KEEP:
        table = log.messages.get(name)
        if table is None:
            continue
        for field, scale in (("TimeUS", 1e-6), ("TimeMS", 1e-3), ("T", 1e-3)):
            if table.has(field) and not (name == "GPS" and field == "TimeMS" and table.has("T")):
                late.update(table.where[table.columns[field] * scale > cut].tolist())
                break
    keep = [int(o) for o, t in zip(offsets, types, strict=True)
            if by_id.get(int(t)) in ARDUPILOT_KEEP and int(o) not in late]
    out = b"".join(data[o:o + int(lengths[buffer[o + 2]])] for o in keep)
    with open(target, "wb") as raw, gzip.GzipFile(fileobj=raw, mode="wb", compresslevel=9, mtime=0) as handle:
        handle.write(out)


def trim_ulog(source: Path, target: Path) -> None:
    from pyulog import ULog

    ulog = ULog(str(source), PX4_TOPICS, disable_str_exceptions=True)
    ulog.write_ulog(str(target))


if __name__ == "__main__":
    ardupilot, corrupt, esc = (Path(p) for p in sys.argv[1:4])
    trim_dataflash(ardupilot, HERE / "ardupilot_copter_log171.bin.gz")
    trim_ulog(corrupt, HERE / "px4_quad_ground_start.ulg")
    trim_ulog(esc, HERE / "px4_quad_hover_start.ulg")
