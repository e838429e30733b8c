#!/usr/bin/env python3
"""Writes this corpus (small AV2 files, valid and broken) from the real fixture log with pyarrow.
Each file is one byte choosing the file it replaces (0 sweep, 1 calibration, 2 poses, 3 annotations;
see fuzz/harness.rs `av2`) followed by the file. Run from the repository root:
    python3 fuzz/corpus/av2/make.py
The data is Argoverse 2's (CC BY-NC-SA 4.0): tests/fixtures/av2/README.md."""
import io
import os

import numpy as np
import pyarrow as pa
import pyarrow.feather as feather

LOG = "tests/fixtures/av2/val/7fab2350-7eaf-3b7e-a39d-6937a4c1bede"
OUT = "fuzz/corpus/av2"
T = 315966265259836000


def write(name, which, table=None, raw=None):
    if raw is None:
        buf = io.BytesIO()
        feather.write_feather(table, buf, compression="lz4")
        raw = buf.getvalue()
    with open(os.path.join(OUT, name), "wb") as f:
        f.write(bytes([which]) + raw)


sweep = feather.read_table(f"{LOG}/sensors/lidar/{T}.feather")
laser = sweep["laser_number"].to_numpy()
keep = np.concatenate([np.where(laser < 32)[0][:400], np.where(laser >= 32)[0][:400]])
small = sweep.take(pa.array(keep))
write("sweep-small", 0, small)
buf = io.BytesIO()
feather.write_feather(small, buf, compression="lz4")
write("sweep-truncated", 0, raw=buf.getvalue()[: len(buf.getvalue()) // 2])
write("sweep-no-laser", 0, small.drop_columns(["laser_number"]))
write("sweep-int-x", 0, small.set_column(0, "x", pa.array(np.arange(len(keep), dtype=np.int32))))
x = small["x"].to_numpy().astype(np.float16)
x[::7] = np.nan
write("sweep-nan", 0, small.set_column(0, "x", pa.array(x)))
write("sweep-uncompressed", 0, raw=(lambda b: (feather.write_feather(small, b, compression="uncompressed"), b.getvalue())[1])(io.BytesIO()))
write("empty", 0, raw=b"")

cal = feather.read_table(f"{LOG}/calibration/egovehicle_SE3_sensor.feather")
write("calibration", 1, cal)
names = cal["sensor_name"].to_pylist()
write("calibration-up-only", 1, cal.filter(pa.array([n != "down_lidar" for n in names])))
qw = cal["qw"].to_numpy().copy()
qw[names.index("down_lidar")] = np.nan
write("calibration-nan", 1, cal.set_column(cal.schema.get_field_index("qw"), "qw", pa.array(qw)))

poses = feather.read_table(f"{LOG}/city_SE3_egovehicle.feather")
ts = poses["timestamp_ns"].to_numpy()
write("poses-near", 2, poses.filter(pa.array(np.abs(ts - T) < 50_000_000)))

ann = feather.read_table(f"{LOG}/annotations.feather")
at = ann["timestamp_ns"].to_numpy()
now = ann.filter(pa.array(at == T))
write("annotations-now", 3, now)
length = now["length_m"].to_numpy().copy()
length[0] = -1.0
write("annotations-negative", 3, now.set_column(now.schema.get_field_index("length_m"), "length_m", pa.array(length)))
