"""Type stubs of the flatport package (see __init__.py for the documentation)."""

import os
from typing import Any, Iterable, Iterator, NamedTuple, Optional, Sequence, Tuple, Union, overload

import numpy as np
import numpy.typing as npt

from . import gpu as gpu

__version__: str
STATUS: dict[int, str]

CameraRef = Union[int, str, None]
FloatRows = Union[npt.NDArray[np.floating], Sequence[Sequence[float]]]
Device = str  # "cpu" | "gpu" | "auto"
Precision = str  # "f64" | "f32"

class Rig:
    def __init__(self, _rig: Any) -> None: ...
    @classmethod
    def from_dict(cls, d: dict) -> Rig: ...
    def to_dict(self) -> dict: ...
    def to_json(self) -> str: ...
    @classmethod
    def from_aquacal(cls, path: Union[str, os.PathLike[str]], master: Optional[str] = None) -> Rig: ...
    def to_aquacal(self, path: Optional[Union[str, os.PathLike[str]]] = None) -> str: ...
    @property
    def camera_names(self) -> list[str]: ...
    @property
    def cameras(self) -> list[dict]: ...
    @property
    def interface(self) -> dict: ...
    def port(self, camera: CameraRef = None) -> dict: ...
    def engine(self, device: Device = "cpu", precision: Precision = "f64") -> str: ...
    @overload
    def project(
        self, points: FloatRows, camera: CameraRef = None, device: Device = "cpu", precision: Precision = "f64"
    ) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.uint32]]: ...
    @overload
    def project(
        self, points: gpu.DeviceArray, camera: CameraRef = None, device: Device = "cpu", precision: Precision = "f64"
    ) -> gpu.DeviceArray: ...
    @overload
    def backproject(
        self, pixels: FloatRows, camera: CameraRef = None, device: Device = "cpu", precision: Precision = "f64"
    ) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.uint32]]: ...
    @overload
    def backproject(
        self, pixels: gpu.DeviceArray, camera: CameraRef = None, device: Device = "cpu", precision: Precision = "f64"
    ) -> gpu.DeviceArray: ...
    def triangulate(
        self,
        matches: FloatRows,
        cameras: Optional[Sequence[CameraRef]] = None,
        device: Device = "cpu",
        precision: Precision = "f64",
    ) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.uint32]]: ...
    def vop(
        self, points: FloatRows, camera: CameraRef = None, device: Device = "cpu", precision: Precision = "f64"
    ) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.uint32]]: ...
    def raymap(
        self, camera: CameraRef = None, device: Device = "cpu", precision: Precision = "f64"
    ) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.uint32]]: ...
    def export_colmap(self, refrac_token: bool = False) -> dict[str, str]: ...
    def export_opencv(self, cameras: Optional[Sequence[CameraRef]] = None) -> str: ...

def load_rig(path: Union[str, os.PathLike[str]]) -> Rig: ...

class CalibrationResult(NamedTuple):
    rig: Optional[Rig]
    report: dict
    sigma: dict

def calibrate(
    rig: Rig,
    observations: Union[dict, str, os.PathLike[str]],
    estimate: Union[str, Iterable[str]] = ...,
    method: str = "auto",
    device: Device = "cpu",
    max_tilt_deg: float = 30.0,
    grid_step_deg: float = 1.5,
    huber: Optional[float] = None,
    max_iterations: int = 200,
    max_rms_px: Optional[float] = None,
    report_dir: Union[str, os.PathLike[str], None] = None,
) -> CalibrationResult: ...

class CalibrationRefused(ValueError):
    report: dict
    def __init__(self, message: str, report: dict) -> None: ...

class ImagesCalibration(NamedTuple):
    rig: Rig
    report: dict
    intrinsics: dict[str, dict]
    ports: list[dict]
    validation: Optional[dict]
    dropped_frames: list[dict]
    dropped_corners: list[str]

def calibrate_images(
    images: Union[str, os.PathLike[str]],
    board: Union[str, os.PathLike[str]],
    port: str,
    *,
    glass: Union[Tuple[float, float], dict[str, Tuple[float, float]], None] = None,
    index_water: float = 1.333,
    index_air: float = 1.0,
    master: Optional[str] = None,
    rig: Union[Rig, str, os.PathLike[str], None] = None,
    frame_step: Optional[int] = None,
    max_frames: Optional[int] = None,
    holdout: float = 0.2,
    output: Union[str, os.PathLike[str], None] = None,
    report: Union[str, os.PathLike[str], None] = None,
    device: Device = "cpu",
    max_tilt_deg: float = 30.0,
    huber: Optional[float] = None,
    max_iterations: int = 200,
    max_rms_px: Optional[float] = None,
    refine_intrinsics: str = "auto",
    report_dir: Union[str, os.PathLike[str], None] = None,
) -> ImagesCalibration: ...

class TargetlessCalibration(NamedTuple):
    rig: Rig
    report: dict
    ports: list[dict]
    rms_px: float
    tracks: int

def calibrate_targetless(
    rig: Union[Rig, str, os.PathLike[str]],
    images: Union[str, os.PathLike[str], Sequence[Sequence[Any]], Sequence[Any]],
    *,
    frames: Union[str, Tuple[Optional[int], Optional[int], Optional[int]], None] = None,
    estimate: Union[str, Iterable[str]] = ("axis", "distance"),
    huber: float = 1.0,
    max_rms_px: float = 1.0,
    max_sigma_axis_deg: float = 0.1,
    max_sigma_distance_mm: float = 2.0,
    output: Union[str, os.PathLike[str], None] = None,
) -> TargetlessCalibration: ...

class Simulation(NamedTuple):
    observations: dict
    truth: dict

def simulate(
    rig: Rig,
    board: Tuple[int, int, float] = (9, 6, 0.04),
    views: int = 20,
    noise: float = 0.1,
    seed: int = 1,
    cameras: Optional[Sequence[CameraRef]] = None,
    max_board_tilt_deg: float = 45.0,
) -> Simulation: ...

class SweepResult(NamedTuple):
    cost: npt.NDArray[np.float64]
    distance: npt.NDArray[np.float64]
    tilt_deg: npt.NDArray[np.float64]
    azimuth_deg: npt.NDArray[np.float64]
    summary: dict

def sweep(
    rig: Rig,
    observations: Union[dict, str, os.PathLike[str]],
    cost: str = "affine-grid",
    tilt_deg: Tuple[float, float, int] = (0.0, 20.0, 64),
    azimuth_deg: Tuple[float, float, int] = (-180.0, 180.0, 64),
    distance: Optional[Tuple[float, float, int]] = None,
    device: Device = "cpu",
    precision: Precision = "f64",
) -> SweepResult: ...

class StereoResult(NamedTuple):
    depth: np.ndarray
    points: np.ndarray
    confidence: np.ndarray
    device: str

class StereoFrame(NamedTuple):
    name: str
    index: int
    depth: np.ndarray
    points: np.ndarray
    confidence: np.ndarray
    device: str

def stereo_frames(
    rig: Rig,
    images: Union[str, os.PathLike[str]],
    frames: Union[str, slice, None] = ...,
    reference: CameraRef = ...,
    depth: Optional[Tuple[float, float]] = ...,
    hypotheses: Optional[int] = ...,
    window: int = ...,
    min_confidence: float = ...,
    device: str = ...,
) -> Iterator[StereoFrame]: ...

def stereo(
    rig: Rig,
    images: Sequence[Any],
    reference: CameraRef = ...,
    depth: Optional[Tuple[float, float]] = ...,
    hypotheses: Optional[int] = ...,
    window: int = ...,
    min_confidence: float = ...,
    device: str = ...,
) -> StereoResult: ...
