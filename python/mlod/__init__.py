"""mlod in Python: the MLOD paper's perturbation model, tr(Xi), fusion, detectors, online
calibration and evaluation on numpy arrays, with the numbers of the ``mlod`` CLI.

    import mlod
    ds = mlod.open("sample_data")
    cloud = ds.fuse(ds.samples[0], alpha=0.1, seed=0)   # points, trace, lidar, intensity
    boxes = ds.detect(ds.samples[0], "mlod-i", alpha=0.1)
    report = ds.evaluate("top", samples=2)               # the dict `mlod eval --json` prints

Every call releases the GIL while Rust works; every error raises :class:`MlodError` with a
message naming the file, sample, case or argument at fault.
"""

from __future__ import annotations

import os
from typing import Any, Dict, List, Optional, Tuple, Union

import numpy as np

from . import _mlod
from ._mlod import MlodError

__all__ = ["MlodError", "Dataset", "open", "perturb", "propagate", "prior", "define_detector"]
__version__ = "0.1.0"

PathLike = Union[str, "os.PathLike[str]"]


def _matrix(a: Any, shape: Tuple[Optional[int], ...], dtype: Any, name: str) -> np.ndarray:
    """``a`` as a C-contiguous array of ``dtype`` (no copy when it already is one), its shape
    checked (``None``: any length)."""
    try:
        arr = np.ascontiguousarray(a, dtype=dtype)
    except (TypeError, ValueError) as e:
        raise MlodError(f"{name}: not an array of numbers ({e})") from None
    if arr.ndim != len(shape) or any(s is not None and s != d for s, d in zip(shape, arr.shape)):
        want = " x ".join("N" if s is None else str(s) for s in shape)
        raise MlodError(f"{name}: expected shape {want}, got {arr.shape}")
    return arr


def _alpha(alpha: Any) -> float:
    try:
        return float(alpha)
    except (TypeError, ValueError):
        raise MlodError(f"alpha: not a number ({alpha!r})") from None


def _seed(seed: Any) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise MlodError(f"seed: expected a non-negative integer, got {seed!r}")
    return int(seed)


class Dataset:
    """A dataset in any format mlod reads (Lyft Level 5, nuScenes, KITTI, Argoverse 2, or
    ``mlod synth``'s output) and the models folder its detectors load from."""

    def __init__(self, path: PathLike, models: Optional[PathLike] = None) -> None:
        self._native = _mlod.Dataset(os.fspath(path), None if models is None else os.fspath(models))

    def __repr__(self) -> str:
        return f"mlod.Dataset({str(self.path)!r}, models={str(self.models)!r})"

    @property
    def path(self) -> str:
        """The folder opened."""
        return str(self._native.path)

    @property
    def models(self) -> str:
        """The models folder the detectors load from."""
        return str(self._native.models)

    @property
    def notes(self) -> List[str]:
        """What the reader noted while opening (the split opened, unknown categories, …)."""
        return list(self._native.notes)

    @property
    def samples(self) -> List[str]:
        """Sample tokens, in the order of ``mlod inspect --list``."""
        return list(self._native.samples)

    def frame(self, sample: str) -> Dict[str, Any]:
        """One sample as the files hold it: ``lidars`` (per LiDAR, primary first: ``channel``,
        ``points`` float32 N x 5 — x, y, z, intensity, ring in the sensor frame — and
        ``extrinsic``, the 4 x 4 sensor-to-base matrix) and ``boxes`` (ground truth in the base
        frame: ``category``, ``center``, ``size_lwh``, ``yaw``, …)."""
        return self._native.frame_dict(str(sample))

    def fuse(self, sample: str, alpha: float = 0.0, seed: int = 0) -> Dict[str, Any]:
        """The fused cloud of ``mlod export`` for this sample, α and seed: ``points`` (N x 3
        float32, base frame; Fortran order, the transpose of one x|y|z buffer), ``trace`` (N, tr(Xi) in m²), ``lidar`` (N, uint8 index into
        ``channels``), ``intensity`` (N), ``channels`` and ``extrinsics`` (the 4 x 4 extrinsic
        each LiDAR was fused with, the drift included)."""
        return self._native.fuse_dict(str(sample), _alpha(alpha), _seed(seed))

    def detect(self, sample: str, case: str, alpha: float = 0.0, seed: int = 0) -> List[Dict[str, Any]]:
        """The boxes of ``case`` (any case of ``mlod detect --help``, or ``ext:NAME`` after
        :func:`define_detector`) on the sample: dicts with the keys of ``mlod detect --json``'s
        detections (``center``, ``size_lwh``, ``yaw``, ``score``, ``category``; base frame)."""
        return self._native.detect_list(str(sample), str(case), _alpha(alpha), _seed(seed))

    def evaluate(
        self, case: str, alpha: float = 0.0, seed: int = 0, samples: Optional[int] = None
    ) -> Dict[str, Any]:
        """Runs ``case`` over the first ``samples`` samples (all by default) and scores it: the
        dict ``mlod eval --case CASE --json [--samples N]`` prints (KITTI-style AP_3D, Lyft mAP)."""
        if samples is not None and (isinstance(samples, bool) or not isinstance(samples, (int, np.integer)) or samples < 1):
            raise MlodError(f"samples: expected a positive integer, got {samples!r}")
        return self._native.evaluate_dict(str(case), _alpha(alpha), _seed(seed), None if samples is None else int(samples))

    def calibrate(self, sample: str, alpha: float = 0.0, seed: int = 0) -> List[Dict[str, Any]]:
        """Online calibration (point-to-plane ICP) of each auxiliary LiDAR from the drift of α and
        seed: per LiDAR the record of ``mlod calibrate --json``'s ``runs`` (``estimate``,
        ``covariance`` 6 x 6 over (ρ, φ), ``error_before``, ``error_after``, ``converged``, …)."""
        return self._native.calibrate_list(str(sample), _alpha(alpha), _seed(seed))


def open(path: PathLike, models: Optional[PathLike] = None) -> Dataset:  # noqa: A001 (mlod.open)
    """Opens a dataset folder; ``models`` defaults to the shipped ``assets/models`` of the checkout
    the package was built from."""
    return Dataset(path, models)


def perturb(extrinsic: Any, alpha: float, seed: int = 0, lidar: str = "LIDAR_FRONT_LEFT") -> np.ndarray:
    """The drifted extrinsic (4 x 4) of auxiliary LiDAR ``lidar`` under the perturbation (α, seed):
    the draw :meth:`Dataset.fuse` applies to that LiDAR (§V-A-3, bounded at ±σ)."""
    m = _matrix(extrinsic, (4, 4), np.float64, "extrinsic")
    return _mlod.perturb(m, _alpha(alpha), _seed(seed), str(lidar))


def propagate(points: Any, extrinsic: Any, alpha: float) -> Tuple[np.ndarray, np.ndarray]:
    """Xi (N x 3 x 3, float32, m²) and tr(Xi) (N) of an auxiliary LiDAR's points (N x 3, sensor
    frame) at ``extrinsic`` (4 x 4) under the prior Θ(α) (eq. 5-9): the paper's §III on your own
    arrays. :meth:`Dataset.fuse`'s ``trace`` is this at the drifted extrinsic."""
    p = _matrix(points, (None, 3), np.float32, "points")
    m = _matrix(extrinsic, (4, 4), np.float64, "extrinsic")
    return _mlod.propagate(p, m, _alpha(alpha))


def prior(alpha: float) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The prior Θ(α) of eq. 9 scaled by α: ``(P, Phi, Z)``, the 3 x 3 covariances of an
    auxiliary LiDAR's translation (m²), rotation (rad²) and of a point's measurement (m²)."""
    p, phi, z = _mlod.prior(_alpha(alpha))
    return p, phi, z


def define_detector(name: str, command: str) -> None:
    """Defines an external detector speaking mlod-detector/1 for the cases ``ext:NAME`` and
    ``mlod-ext:NAME`` (as the CLI's ``--detector NAME=COMMAND``; docs/external.md)."""
    _mlod.define_detector(str(name), str(command))
