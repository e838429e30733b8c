"""Shared helpers for the devkit reference scripts in tests/devkit/.

Pure numpy rigid-transform helpers (quaternions are [w, x, y, z], Lyft/nuScenes order) plus
a helper that opens the read-only real fixture tables with the official `LyftDataset`.
Run with the devkit venv: /work/devkit-venv/bin/python (see requirements.txt / NOTES.md).
"""

import math
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

REAL_TABLES = Path(os.environ.get("MLOD_REAL_TABLES", "/work/shared/lyft-real-tables"))
VERSION_DIR = "v1.01-train"
LIDAR_CHANNELS = ("LIDAR_TOP", "LIDAR_FRONT_LEFT", "LIDAR_FRONT_RIGHT")


def devkit_version() -> str:
    try:
        from importlib.metadata import version

        return version("lyft-dataset-sdk")
    except Exception:  # pragma: no cover
        return "unknown"


# --------------------------------------------------------------------------- quaternion / SE(3)


def quat_to_matrix(q_wxyz) -> np.ndarray:
    """Rotation matrix of a quaternion [w, x, y, z] (normalised first, as pyquaternion does)."""
    w, x, y, z = np.asarray(q_wxyz, dtype=np.float64) / np.linalg.norm(q_wxyz)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_to_quat(R) -> np.ndarray:
    """Quaternion [w, x, y, z] of a rotation matrix (Shepperd's method), canonicalised to w >= 0."""
    R = np.asarray(R, dtype=np.float64)
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    if tr > 0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = [(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s]
    q = np.array(q)
    q /= np.linalg.norm(q)
    return -q if q[0] < 0 else q


def se3(translation, rotation_wxyz) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = quat_to_matrix(rotation_wxyz)
    T[:3, 3] = np.asarray(translation, dtype=np.float64)
    return T


def se3_inv(T) -> np.ndarray:
    Ti = np.eye(4)
    Ti[:3, :3] = T[:3, :3].T
    Ti[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return Ti


def yaw_zyx(R) -> float:
    """Heading of the box x-axis: yaw of R = Rz(yaw) Ry(pitch) Rx(roll), i.e. atan2(R10, R00)."""
    return math.atan2(R[1, 0], R[0, 0])


def pitch_roll_zyx(R):
    pitch = math.asin(max(-1.0, min(1.0, -R[2, 0])))
    roll = math.atan2(R[2, 1], R[2, 2])
    return pitch, roll


def wrap_angle(a: float) -> float:
    """Wrap to (-pi, pi]."""
    a = math.fmod(a + math.pi, 2.0 * math.pi)
    if a <= 0:
        a += 2.0 * math.pi
    return a - math.pi


def rotation_angle_between(q1_wxyz, q2_wxyz) -> float:
    """Angle (rad) of the relative rotation between two quaternions (sign-insensitive)."""
    q1 = np.asarray(q1_wxyz, dtype=np.float64) / np.linalg.norm(q1_wxyz)
    q2 = np.asarray(q2_wxyz, dtype=np.float64) / np.linalg.norm(q2_wxyz)
    d = min(1.0, abs(float(np.dot(q1, q2))))
    return 2.0 * math.acos(d)


def lidar_extrinsics_via_global(lyftd, sample_record, base_channel="LIDAR_TOP"):
    """T^b_{l_i} for every LiDAR key frame of a sample, computed in numpy through the global frame:

        T_b<-li = (T_global<-ego_b . T_ego<-b)^-1 . T_global<-ego_i . T_ego<-li

    Each sample_data row has its own ego_pose, so different ego poses per sweep are honoured.
    Returns {channel: {"translation": [3], "rotation_wxyz": [4], "matrix": 4x4 ndarray}}.
    """

    def T_global_from_sensor(sd_token):
        sd = lyftd.get("sample_data", sd_token)
        cs = lyftd.get("calibrated_sensor", sd["calibrated_sensor_token"])
        ep = lyftd.get("ego_pose", sd["ego_pose_token"])
        return se3(ep["translation"], ep["rotation"]) @ se3(cs["translation"], cs["rotation"])

    T_g_b = T_global_from_sensor(sample_record["data"][base_channel])
    T_b_g = se3_inv(T_g_b)
    out = {}
    for channel, sd_token in sorted(sample_record["data"].items()):
        sd = lyftd.get("sample_data", sd_token)
        if sd["sensor_modality"] != "lidar":
            continue
        T = T_b_g @ T_global_from_sensor(sd_token)
        out[channel] = {
            "translation": [float(v) for v in T[:3, 3]],
            "rotation_wxyz": [float(v) for v in matrix_to_quat(T[:3, :3])],
            "matrix": T,
        }
    return out


# --------------------------------------------------------------------------- opening datasets


def open_dataset(data_path, json_path=None, verbose=False):
    """Open a dataset with the official devkit. json_path defaults to the version folder inside data_path."""
    from lyft_dataset_sdk.lyftdataset import LyftDataset

    data_path = Path(data_path)
    if json_path is None:
        json_path = find_version_dir(data_path)
    return LyftDataset(data_path=str(data_path), json_path=str(json_path), verbose=verbose)


def find_version_dir(data_path: Path) -> Path:
    """The folder holding the *.json tables: data_path itself, data_path/v1.01-train, or the only
    sub-folder containing sample.json."""
    data_path = Path(data_path)
    if (data_path / "sample.json").is_file():
        return data_path
    if (data_path / VERSION_DIR / "sample.json").is_file():
        return data_path / VERSION_DIR
    candidates = sorted(p.parent for p in data_path.glob("*/sample.json"))
    if len(candidates) == 1:
        return candidates[0]
    raise FileNotFoundError(f"no table folder (with sample.json) found in {data_path}")


def staged_real_fixture(real_tables: Path = REAL_TABLES) -> Path:
    """Copy the read-only real fixture into a fresh temp dir and add the minimum the devkit needs
    to open it: the map raster PNG named by map.json (the devkit asserts it exists at init, but
    only reads it lazily, so a 1x1 black placeholder suffices). No .bin file is needed.
    Caller removes the returned directory."""
    import json

    from PIL import Image

    tmp = Path(tempfile.mkdtemp(prefix="mlod-devkit-real-"))
    (tmp / VERSION_DIR).mkdir()
    for table in sorted((real_tables / VERSION_DIR).glob("*.json")):
        shutil.copyfile(table, tmp / VERSION_DIR / table.name)  # copyfile: don't keep the read-only mode
    with open(tmp / VERSION_DIR / "map.json") as f:
        maps = json.load(f)
    for m in maps:
        png = tmp / m["filename"]
        png.parent.mkdir(parents=True, exist_ok=True)
        Image.new("L", (1, 1), 0).save(png)
    return tmp
