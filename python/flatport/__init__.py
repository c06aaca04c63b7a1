"""Refraction through flat underwater camera ports, exactly: the Python face of the flatport crate.

Cameras sit in air behind a flat port (air → glass → water). A :class:`Rig` projects 3-D points
(master camera frame, metres) to pixels, back-projects pixels to rays in the water, triangulates
stereo matches and computes Virtual Object Points, in batches of any size, on the CPU (the exact
f64 reference, all cores) or on a GPU (WGSL kernels through wgpu, f32 or f64). Conventions are the
crate's (docs/DESIGN.md): OpenCV camera frames, pixel (0, 0) is the centre of the top-left pixel,
the first camera of the rig is the master and defines the world frame.

Rows without an answer (a point inside the glass, total internal reflection, …) are NaN, and their
``status`` is the reason's code (:data:`STATUS`); every other row has status 0, as the CLI writes.

>>> import flatport, numpy as np
>>> rig = flatport.load_rig("data/example_rig.json")                      # doctest: +SKIP
>>> uv, status = rig.project(np.array([[0.2, -0.1, 1.5]]), camera="left")  # doctest: +SKIP
>>> rays, status = rig.backproject(uv, camera="left")                      # doctest: +SKIP
"""

from __future__ import annotations

import json
import os
from typing import Any, Iterable, Iterator, NamedTuple, Optional, Sequence, Tuple, Union

import numpy as np

from . import _flatport
from ._flatport import __version__
from . import gpu

__all__ = [
    "Rig",
    "load_rig",
    "calibrate",
    "CalibrationResult",
    "calibrate_images",
    "ImagesCalibration",
    "CalibrationRefused",
    "calibrate_targetless",
    "TargetlessCalibration",
    "simulate",
    "Simulation",
    "sweep",
    "SweepResult",
    "stereo",
    "stereo_frames",
    "StereoFrame",
    "StereoResult",
    "STATUS",
    "gpu",
    "__version__",
]

#: Status codes of rows without an answer (0: the row has one), as the crate's ``NoSolution``.
STATUS = {
    0: "ok",
    1: "outside the lens model's one-to-one region",
    2: "ray misses the interface",
    3: "total internal reflection",
    4: "point not in the water (in the air or a layer)",
    5: "beyond the camera's field of view",
    6: "degenerate geometry (parallel rays)",
    7: "root finder did not converge",
    8: "beyond the floating-point range",
}

_DEVICES = ("cpu", "gpu", "auto")
_PRECISIONS = ("f64", "f32")

CameraRef = Union[int, str, None]


def _rows(name: str, value: Any, width: int) -> np.ndarray:
    """``value`` as a C-contiguous float64 (N, width) array: an ndarray of that kind as it is (no
    copy), another float array converted, a list of numbers converted. Raises TypeError naming
    ``name`` for a non-float array and ValueError for a wrong shape."""
    if isinstance(value, np.ndarray):
        if value.dtype.kind != "f":
            raise TypeError(f"{name} must be a float array (float16/32/64), got dtype {value.dtype}")
        array = value
    else:
        try:
            array = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError) as error:
            raise TypeError(f"{name} must be an array of numbers: {error}") from None
    if array.ndim != 2 or array.shape[1] != width:
        raise ValueError(f"{name} must have shape (N, {width}), got {array.shape}")
    return np.ascontiguousarray(array, dtype=np.float64)


def _check_engine(device: str, precision: str) -> None:
    if device not in _DEVICES:
        raise ValueError(f"device must be one of {_DEVICES}, got {device!r}")
    if precision not in _PRECISIONS:
        raise ValueError(f"precision must be one of {_PRECISIONS}, got {precision!r}")
    if device == "cpu" and precision == "f32":
        raise ValueError("precision='f32' runs on the GPU kernels: the CPU path is f64 only (use device='gpu' or 'auto')")


def _json_argument(name: str, value: Any) -> str:
    """A dict (JSON object), a path to a JSON file, or JSON text, as JSON text."""
    if isinstance(value, dict):
        return json.dumps(value)
    if isinstance(value, (str, os.PathLike)):
        text = str(value)
        if text.lstrip().startswith("{"):
            return text
        with open(value, encoding="utf-8") as file:
            return file.read()
    raise TypeError(f"{name} must be a dict, a path to a JSON file or JSON text, got {type(value).__name__}")


class Rig:
    """Cameras calibrated in air behind one shared flat port.

    Build one with :func:`load_rig` (a rig JSON file) or :meth:`Rig.from_dict`. Each rig keeps one
    engine per (device, precision) it was asked for, so a GPU context is made once and reused.
    Compute releases the GIL.

    >>> rig = flatport.Rig.from_dict({                                    # doctest: +SKIP
    ...     "cameras": [{"name": "left", "width": 1280, "height": 1024,
    ...                  "fx": 864.91, "fy": 864.91, "cx": 640.0, "cy": 512.0}],
    ...     "interface": {"normal": [0, 0, 1], "distance": 0.02,
    ...                   "layers": [{"thickness": 0.014, "index": 1.473}]}})
    >>> rig.camera_names                                                   # doctest: +SKIP
    ['left']
    """

    __slots__ = ("_rig",)

    def __init__(self, _rig: Any) -> None:
        if not isinstance(_rig, _flatport._Rig):
            raise TypeError("use flatport.load_rig(path) or flatport.Rig.from_dict(d)")
        self._rig = _rig

    # --- construction and description -------------------------------------------------------

    @classmethod
    def from_dict(cls, d: dict) -> "Rig":
        """A rig from the rig JSON's structure (docs/DESIGN.md §1): ``cameras`` and ``interface``.
        Unknown keys and invalid values raise ValueError naming them."""
        if not isinstance(d, dict):
            raise TypeError(f"Rig.from_dict takes a dict, got {type(d).__name__}")
        return cls(_flatport._Rig.from_json(json.dumps(d), "<dict>"))

    def to_dict(self) -> dict:
        """The rig as the rig JSON's structure (what :meth:`from_dict` takes back)."""
        return json.loads(self._rig.to_json())

    def to_json(self) -> str:
        """The rig file's text."""
        return self._rig.to_json()

    @classmethod
    def from_aquacal(cls, path: Union[str, os.PathLike], master: Optional[str] = None) -> "Rig":
        """A rig from AquaCal's ``calibration.json`` (what ``flatport rig from-aquacal`` reads;
        docs/rigs.md): the first camera in the file (or ``master``) becomes the master, the water
        surface the shared interface. Errors raise ValueError naming the file, JSON path and value."""
        return cls(_flatport._Rig.from_aquacal(os.fspath(path), master))

    def to_aquacal(self, path: Optional[Union[str, os.PathLike]] = None) -> str:
        """The rig as AquaCal's ``calibration.json`` (what ``flatport export aquacal`` writes;
        docs/export.md), written to ``path`` when given; returns the text. A rig AquaCal cannot hold
        (glass layers, ports per camera that are not parallel) raises ValueError saying why."""
        text = self._rig.to_aquacal()
        if path is not None:
            with open(path, "w", encoding="utf-8") as file:
                file.write(text)
        return text

    @property
    def camera_names(self) -> list:
        """Names of the cameras, master first."""
        return self._rig.camera_names()

    @property
    def cameras(self) -> list:
        """Every camera as a dict: name, size, intrinsics, distortion, rotation, translation."""
        return self.to_dict()["cameras"]

    @property
    def interface(self) -> dict:
        """The shared port in the master frame: normal, distance (air layer d), layers, indices."""
        return self.to_dict()["interface"]

    def port(self, camera: CameraRef = None) -> dict:
        """The shared port as ``camera`` sees it, in that camera's own frame (DESIGN.md §3b's
        per-camera form, colmap_underwater's FLATPORT convention): ``normal`` R_k·n, ``distance``
        d_k = d − n·C_k, ``layers``, ``index_air``, ``index_water``, and the camera's ``centre``
        C_k in the master frame."""
        index = self._camera_index(camera, "camera")
        normal, distance, centre = self._rig.port_in_camera(index)
        interface = self.interface
        return {
            "normal": list(normal),
            "distance": distance,
            "layers": interface.get("layers", []),
            "index_air": interface.get("index_air", 1.0),
            "index_water": interface.get("index_water", 1.333),
            "centre": list(centre),
        }

    def engine(self, device: str = "cpu", precision: str = "f64") -> str:
        """Builds (or reuses) the engine of ``device`` and ``precision`` and says what runs."""
        _check_engine(device, precision)
        return self._rig.describe_engine(device, precision)

    def __repr__(self) -> str:
        return f"flatport.Rig(cameras={self.camera_names})"

    def _camera_index(self, camera: CameraRef, name: str) -> int:
        names = self.camera_names
        if camera is None:
            return 0
        if isinstance(camera, (int, np.integer)) and not isinstance(camera, bool):
            if not 0 <= camera < len(names):
                raise ValueError(f"{name}={camera}: the rig has cameras 0..{len(names) - 1} ({', '.join(names)})")
            return int(camera)
        if isinstance(camera, str):
            if camera in names:
                return names.index(camera)
            if camera.isdigit() and int(camera) < len(names):
                return int(camera)
            raise ValueError(f"{name}={camera!r}: no such camera in the rig (cameras: {', '.join(names)})")
        raise TypeError(f"{name} must be a camera name or index, got {type(camera).__name__}")

    # --- geometry ---------------------------------------------------------------------------

    def project(self, points: Any, camera: CameraRef = None, device: str = "cpu", precision: str = "f64") -> Tuple[np.ndarray, np.ndarray]:
        """Projects points (N, 3) (x, y, z in the master frame, metres) through the port to raw
        (distorted) pixels of ``camera`` (name or index; default the master).

        Returns ``(uv, status)``: uv (N, 2) float64, NaN where status (N,) uint32 is not 0.

        >>> uv, status = rig.project([[0.2, -0.1, 1.5]], camera="right")  # doctest: +SKIP

        Given a :class:`flatport.gpu.DeviceArray` of points, returns a device array of pixels
        (on the GPU, no copy; ``device`` and ``precision`` are the array's own).
        """
        if isinstance(points, gpu.DeviceArray):
            return gpu.project(self, points, [camera if camera is not None else 0])[0]
        _check_engine(device, precision)
        return self._rig.project(_rows("points", points, 3), self._camera_index(camera, "camera"), device, precision)

    def backproject(self, pixels: Any, camera: CameraRef = None, device: str = "cpu", precision: str = "f64") -> Tuple[np.ndarray, np.ndarray]:
        """Back-projects raw pixels (N, 2) of ``camera`` to rays in the water.

        Returns ``(rays, status)``: rays (N, 6) = origin on the outer interface (x, y, z) and unit
        direction in the water, master frame; NaN where status is not 0.

        >>> rays, status = rig.backproject([[640.0, 512.0]])  # doctest: +SKIP

        Given a :class:`flatport.gpu.DeviceArray` of pixels, returns a device array of rays
        (on the GPU, no copy; ``device`` and ``precision`` are the array's own).
        """
        if isinstance(pixels, gpu.DeviceArray):
            return gpu.backproject(self, pixels, camera)
        _check_engine(device, precision)
        return self._rig.backproject(_rows("pixels", pixels, 2), self._camera_index(camera, "camera"), device, precision)

    def triangulate(self, matches: Any, cameras: Optional[Sequence[CameraRef]] = None, device: str = "cpu", precision: str = "f64") -> Tuple[np.ndarray, np.ndarray]:
        """Triangulates matches (N, 4) = (u_a, v_a, u_b, v_b), raw pixels in ``cameras = (a, b)``
        (default the first two cameras), refractively: both pixels are back-projected into the
        water and the point is the midpoint of the rays' closest approach.

        Returns ``(xyz_residual, status)``: (N, 4) = x, y, z (master frame) and the rays'
        distance (metres); NaN where status is not 0 (nearly parallel rays, …).

        >>> xyzr, status = rig.triangulate(np.hstack([uv_left, uv_right]), cameras=("left", "right"))  # doctest: +SKIP
        """
        _check_engine(device, precision)
        a, b = self._camera_pair(cameras)
        return self._rig.triangulate(_rows("matches", matches, 4), a, b, device, precision)

    def _camera_pair(self, cameras: Optional[Sequence[CameraRef]]) -> Tuple[int, int]:
        """The indices (a, b) of a pair of names or indices (default the first two cameras)."""
        if cameras is None:
            if len(self.camera_names) < 2:
                raise ValueError("triangulate needs two cameras; this rig has one")
            return 0, 1
        if isinstance(cameras, str) or len(cameras) != 2:
            raise ValueError(f"cameras must be a pair (a, b) of names or indices, got {cameras!r}")
        a, b = self._camera_index(cameras[0], "cameras[0]"), self._camera_index(cameras[1], "cameras[1]")
        if a == b:
            raise ValueError(f"cameras names camera {a} twice")
        return a, b

    def vop(self, points: Any, camera: CameraRef = None, device: str = "cpu", precision: str = "f64") -> Tuple[np.ndarray, np.ndarray]:
        """Virtual Object Points of points (N, 3) seen by ``camera``.

        Returns ``(vops, status)``: (N, 6) = depth (distance from the outer interface along the
        axis, thesis eq 4.7), vop_distance (eq 4.8, negative inside the glass), the VOP's x, y, z
        (master frame) and the angle of incidence in air (radians); NaN where status is not 0.
        """
        _check_engine(device, precision)
        return self._rig.vop(_rows("points", points, 3), self._camera_index(camera, "camera"), device, precision)

    def raymap(self, camera: CameraRef = None, device: str = "cpu", precision: str = "f64") -> Tuple[np.ndarray, np.ndarray]:
        """The water ray of every pixel of ``camera``: ``(rays, status)`` with rays (H, W, 6)
        float64, rays[v, u] the ray of pixel (u, v) exactly as :meth:`backproject` gives it, and
        status (H, W). On the GPU the pixel grid is generated in the shader."""
        _check_engine(device, precision)
        return self._rig.raymap(self._camera_index(camera, "camera"), device, precision)

    # --- exports ----------------------------------------------------------------------------

    def export_colmap(self, refrac_token: bool = False) -> dict:
        """The files ``flatport export colmap`` writes, by name: colmap_underwater's
        ``cameras.txt`` (lens + FLATPORT per camera, the port in that camera's frame, COLMAP's pixel
        centres), COLMAP's rig configuration ``rig_config.json`` and ``rigs.txt`` (COLMAP 3.12).
        ``refrac_token`` writes ``… REFRAC FLATPORT …`` for the COLMAP 3.12 based port.

        >>> files = rig.export_colmap()                                    # doctest: +SKIP
        >>> print(files["cameras.txt"])                                    # doctest: +SKIP
        """
        cameras, config, rigs = self._rig.export_colmap(bool(refrac_token))
        return {"cameras.txt": cameras, "rig_config.json": config, "rigs.txt": rigs}

    def export_opencv(self, cameras: Optional[Sequence[CameraRef]] = None) -> str:
        """The in-air calibration as OpenCV FileStorage YAML: cameras ``(a, b)`` (default the
        first two, or the only one) as ``M1 D1 M2 D2 R T``, or one camera ``(a,)`` as ``M1 D1``."""
        if cameras is None:
            picked = [0, 1] if len(self.camera_names) > 1 else [0]
        else:
            picked = [self._camera_index(c, "cameras") for c in cameras]
            if len(picked) not in (1, 2):
                raise ValueError(f"cameras must name one or two cameras, got {cameras!r}")
        return self._rig.export_opencv(*picked)


def load_rig(path: Union[str, os.PathLike]) -> Rig:
    """Reads a rig JSON file (docs/DESIGN.md §1). Errors name the file, line and field."""
    return Rig(_flatport._Rig.load(os.fspath(path)))


# --- calibration ----------------------------------------------------------------------------


class CalibrationResult(NamedTuple):
    """What :func:`calibrate` found."""

    #: The input rig with everything estimated replaced, or None when the fit was refused
    #: (``report["fits"]`` is False: the reprojection RMS is above ``max_rms_px``, by default 3 px
    #: and a few times the corner noise seen in the images).
    rig: Optional[Rig]
    #: The full report (the CLI's ``--report`` JSON) as a dict.
    report: dict
    #: Standard deviations: ``tilt_deg``, ``azimuth_deg``, ``air_distance`` (metres; None for the
    #: consecutive method, which has no covariance; the first port's in the general calibration,
    #: every port's and camera's in ``report``) and ``sigma_px`` (the corner noise estimate).
    sigma: dict


def calibrate(
    rig: Rig,
    observations: Any,
    estimate: Union[str, Iterable[str]] = ("axis", "distance"),
    method: str = "auto",
    device: str = "cpu",
    max_tilt_deg: float = 30.0,
    grid_step_deg: float = 1.5,
    huber: Optional[float] = None,
    max_iterations: int = 200,
    max_rms_px: Optional[float] = None,
    report_dir: Optional[Union[str, os.PathLike]] = None,
) -> CalibrationResult:
    """Calibrates a rig's port(s) (and, when asked, layer thicknesses and extrinsics) from views of
    a target, as ``flatport calibrate`` does.

    ``observations`` is the observations JSON (a dict, a path or JSON text): a ``board`` (rows,
    cols, square) or a 3-D ``target`` (points), and per view the corners of every camera that saw
    it, keyed by rig camera name (the stereo form with ``left``/``right`` is read too).
    ``estimate`` names what is estimated, from ``axis``, ``distance``, ``layers`` (every layer
    thickness), ``layer:K`` (layer K only) and ``extrinsics`` (a comma-separated string or a
    list). Every rig (one camera, N cameras, a shared port or a port per camera, a board or a
    3-D target) runs one pipeline: where cameras share a port over a board the thesis'
    consecutive method starts it, then maximum likelihood; the report lists every port and
    camera (``report["ports"]``, ``report["cameras"]``). ``method`` is ``consecutive``,
    ``simultaneous`` or ``auto``; ``device`` ``cpu``, ``gpu`` or ``auto`` (GPU kernels in f64,
    for the consecutive method's cost batches). ``report_dir`` also writes the report page there
    (``index.html`` with pictures, σ and which views to add), as ``--report-dir`` does.

    >>> scene = flatport.simulate(rig, views=15, noise=0.125, seed=3)             # doctest: +SKIP
    >>> result = flatport.calibrate(start_rig, scene.observations)                # doctest: +SKIP
    >>> result.rig.interface["normal"], result.sigma["tilt_deg"]                 # doctest: +SKIP
    """
    if not isinstance(rig, Rig):
        raise TypeError(f"rig must be a flatport.Rig, got {type(rig).__name__}")
    words = [part.strip() for part in (estimate.split(",") if isinstance(estimate, str) else estimate)]
    if device not in _DEVICES:
        raise ValueError(f"device must be one of {_DEVICES}, got {device!r}")
    calibrated, report = _flatport.calibrate(
        rig._rig, _json_argument("observations", observations), ",".join(words), method, device, float(max_tilt_deg),
        float(grid_step_deg), None if huber is None else float(huber), int(max_iterations),
        None if max_rms_px is None else float(max_rms_px),
        None if report_dir is None else os.fspath(report_dir),
    )
    report = json.loads(report)
    # The first port's (every port's is in report["ports"], every camera's in report["cameras"]).
    port = report["ports"][0]
    sigma = {
        "tilt_deg": port["tilt_deg"]["std"],
        "azimuth_deg": port["azimuth_deg"]["std"],
        "air_distance": port["distance"]["std"],
        "sigma_px": report.get("sigma_px"),
    }
    return CalibrationResult(Rig(calibrated) if calibrated is not None else None, report, sigma)


class CalibrationRefused(ValueError):
    """:func:`calibrate_images` fitted a rig that does not fit the images (the reprojection RMS
    above ``max_rms_px``), or :func:`calibrate_targetless` one whose port the scene does not pin
    down (a σ above its limit): no rig is returned, as ``flatport calibrate --images`` writes
    none. The message says what the data look like (for a targetless fit: which parameter, its σ,
    the limit and what it trades off with); ``report`` is the full report (a dict), as written to
    ``report=`` when given."""

    def __init__(self, message: str, report: dict) -> None:
        super().__init__(message)
        self.report = report


class ImagesCalibration(NamedTuple):
    """What :func:`calibrate_images` found: ``flatport calibrate --images``' rig and report."""

    #: The calibrated rig: the cameras' lenses (fitted in air, or the ``rig`` given), the
    #: extrinsics (the master camera defines the frame) and the port(s).
    rig: Rig
    #: The full report (the CLI's ``--report`` JSON) as a dict.
    report: dict
    #: Per camera name, its in-air fit (empty with ``rig=``): ``fx``, ``fy``, ``cx``, ``cy``
    #: (pixels), ``distortion`` (5,) float64 (k1, k2, p1, p2, k3), ``std`` (the same keys, σ),
    #: ``rms_px``, ``view_rms_px`` (views,) float64 (NaN for a view left out), ``outliers`` and
    #: ``excluded`` (views left out and why), ``lens_terms`` and ``lens_terms_why``.
    intrinsics: dict
    #: Every port: ``name``, ``normal`` (3,) float64 in the master frame, ``tilt_deg``,
    #: ``azimuth_deg``, ``distance`` (air layer, metres), each ``{"value", "std"}``, and
    #: ``thicknesses`` (the glass layers, known: σ None).
    ports: list
    #: The held-out frames (None when none were held out): ``frames``, ``rms_px`` (their
    #: reprojection RMS), ``corner_pairs`` (neighbouring corners triangulated),
    #: ``median_distance_error_mm``, ``median_distance_error_percent_of_square``,
    #: ``rms_distance_error_mm``.
    validation: Optional[dict]
    #: Underwater frames dropped as outliers: ``{"frame", "why"}`` each.
    dropped_frames: list
    #: Corners left out after the first fit, a line each.
    dropped_corners: list


def _intrinsics_arrays(fit: dict) -> dict:
    """A camera's in-air fit from the report with its lists as float64 arrays (None → NaN)."""
    fit = dict(fit)
    fit["distortion"] = np.asarray(fit["distortion"], dtype=np.float64)
    fit["std"] = dict(fit["std"], distortion=np.asarray(fit["std"]["distortion"], dtype=np.float64))
    fit["view_rms_px"] = np.array([np.nan if r is None else r for r in fit["view_rms_px"]], dtype=np.float64)
    return fit


def _glass_rows(glass: Any) -> list:
    """``glass`` as ``(camera or None, thickness, index)`` rows: a pair for every port, or a dict
    camera name → pair."""
    def pair(value: Any, where: str) -> Tuple[float, float]:
        try:
            thickness, index = value
            return float(thickness), float(index)
        except (TypeError, ValueError):
            raise ValueError(f"{where} must be a pair (thickness in metres, refractive index), e.g. (0.01, 1.49), got {value!r}") from None

    if glass is None:
        return []
    if isinstance(glass, dict):
        rows = []
        for camera, value in glass.items():
            if not isinstance(camera, str) or not camera:
                raise TypeError(f"glass: the keys are camera names, got {camera!r}")
            rows.append((camera, *pair(value, f"glass[{camera!r}]")))
        return rows
    return [(None, *pair(glass, "glass"))]


def _optional_count(name: str, value: Optional[int], smallest: int) -> Optional[int]:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < smallest:
        raise ValueError(f"{name} must be a whole number from {smallest}, got {value!r}")
    return int(value)


def calibrate_images(
    images: Union[str, os.PathLike],
    board: Union[str, os.PathLike],
    port: str,
    *,
    glass: Any = None,
    index_water: float = 1.333,
    index_air: float = 1.0,
    master: Optional[str] = None,
    rig: Optional[Union[Rig, str, os.PathLike]] = None,
    frame_step: Optional[int] = None,
    max_frames: Optional[int] = None,
    holdout: float = 0.2,
    output: Optional[Union[str, os.PathLike]] = None,
    report: Optional[Union[str, os.PathLike]] = None,
    device: str = "cpu",
    max_tilt_deg: float = 30.0,
    huber: Optional[float] = None,
    max_iterations: int = 200,
    max_rms_px: Optional[float] = None,
    refine_intrinsics: str = "auto",
    report_dir: Optional[Union[str, os.PathLike]] = None,
) -> ImagesCalibration:
    """A whole rig from images or videos of a board alone, as ``flatport calibrate --images DIR
    --board BOARD.json --port …`` (docs/images.md): every camera's lens from its in-air views,
    then the extrinsics and the port(s) from the synchronized frames under water.

    ``images`` holds ``air/<camera>/`` (each camera's in-air views) and ``water/<camera>/``
    (synchronized frames under water), each folder images or one video; ``board`` the board's
    BOARD.json (ChArUco or chessboard). ``port``: ``"surface"`` (a bare water surface in front of
    every camera), ``"shared"`` (one port with its glass) or ``"housings"`` (a port per camera).
    ``glass``: ``(thickness, index)`` (metres) for every port, or a dict camera name → pair for
    each housing's own. ``rig`` (a :class:`Rig` or a rig file): the cameras' in-air calibration
    instead of ``air/``; with neither ``air/`` nor ``rig``, every lens comes from the underwater
    frames with the port(s). The report's ``verdict`` says good, usable or poor and why (a poor
    one raises :class:`CalibrationRefused`). ``refine_intrinsics``: ``"auto"`` (refine the lenses
    under water where the held-out frames say it helps), ``"never"`` or ``"always"``. ``master``: the camera whose frame is the rig's (default the first folder
    by name). ``frame_step``: read every n-th frame; ``max_frames``: most frames used per camera
    (default 40 in air, 60 under water); ``holdout``: the share of underwater frames held out and
    reported on. ``output`` and ``report`` write the rig and the report files as the CLI does;
    ``report_dir`` the report page (``index.html`` with pictures, σ and which views to add), as
    ``--report-dir`` does.
    ``device``, ``max_tilt_deg``, ``huber``, ``max_iterations`` and ``max_rms_px`` are
    :func:`calibrate`'s. The detection and the fit release the GIL.

    Bad input (a missing folder, an unreadable image, a camera the board is never seen by, …)
    raises ValueError with the library's message, naming the folder or file. A rig that does not
    fit the images raises :class:`CalibrationRefused` (a ValueError) with the report: no rig is
    returned and ``output`` is not written.

    >>> result = flatport.calibrate_images("set", "board.json", "shared", glass=(0.014, 1.473))  # doctest: +SKIP
    >>> result.ports[0]["tilt_deg"], result.validation["rms_px"]                                 # doctest: +SKIP
    """
    if port not in ("surface", "shared", "housings"):
        raise ValueError(f"port must be 'surface', 'shared' or 'housings', got {port!r}")
    if device not in _DEVICES:
        raise ValueError(f"device must be one of {_DEVICES}, got {device!r}")
    holdout = float(holdout)
    if not 0.0 <= holdout < 1.0:
        raise ValueError(f"holdout is a share of the frames, from 0 to below 1 (at most half are held out), got {holdout}")
    if refine_intrinsics not in ("auto", "never", "always"):
        raise ValueError(f"refine_intrinsics must be 'auto', 'never' or 'always', got {refine_intrinsics!r}")
    rig_label = "rig"
    if rig is not None and not isinstance(rig, Rig):
        if not isinstance(rig, (str, os.PathLike)):
            raise TypeError(f"rig must be a flatport.Rig or a path to a rig file, got {type(rig).__name__}")
        rig_label = os.fspath(rig)
        rig = load_rig(rig)
    fspath = lambda p: None if p is None else os.fspath(p)  # noqa: E731
    calibrated, text, refused = _flatport.calibrate_images(
        os.fspath(images), os.fspath(board), port, _glass_rows(glass), float(index_water), float(index_air), master,
        None if rig is None else rig._rig, rig_label, _optional_count("frame_step", frame_step, 1),
        _optional_count("max_frames", max_frames, 3), holdout, fspath(output), fspath(report), device,
        float(max_tilt_deg), None if huber is None else float(huber), int(max_iterations),
        None if max_rms_px is None else float(max_rms_px), refine_intrinsics, fspath(report_dir),
    )
    full = json.loads(text)
    if refused is not None:
        raise CalibrationRefused(refused, full)
    ports = [dict(p, normal=np.asarray(p["normal"], dtype=np.float64)) for p in full["ports"]]
    return ImagesCalibration(
        rig=Rig(calibrated),
        report=full,
        intrinsics={fit["camera"]: _intrinsics_arrays(fit) for fit in full["intrinsics"]},
        ports=ports,
        validation=full["held_out"],
        dropped_frames=full["dropped_frames"],
        dropped_corners=full["dropped_corners"],
    )


class TargetlessCalibration(NamedTuple):
    """What :func:`calibrate_targetless` found: ``flatport calibrate --targetless``' rig and the
    fit's report."""

    #: The input rig with its port(s) fitted (cameras and extrinsics as given).
    rig: Rig
    #: The report as a dict: ``ports``, ``rms_px``, ``candidates`` (tracks matched), ``tracks``
    #: (kept in the fit), ``observations``, ``matches_per_camera``, ``starts``, ``termination``,
    #: ``overlap``, ``unpinned`` and ``pinned``.
    report: dict
    #: Every port: ``name``, ``normal`` (3,) float64 (in the frame the rig file gives the port
    #: in), ``tilt_deg``, ``azimuth_deg``, ``axis_std_deg`` (σ of the axis along its worst
    #: direction, None when not estimated), ``distance`` ``{"value", "std"}`` (metres; for a water
    #: surface its height) and ``thicknesses`` (each ``{"value", "std"}``).
    ports: list
    #: RMS reprojection error of the final fit, pixels.
    rms_px: float
    #: Tracks (a master corner and its matches) kept in the fit.
    tracks: int


def _targetless_frames(images: Any) -> list:
    """``images`` as frames of grey float32 images: a sequence of frames, each a sequence with one
    image per rig camera, or one frame (a sequence of images)."""
    frames = list(images)
    if not frames:
        raise ValueError("images holds no frame")
    if isinstance(frames[0], np.ndarray) and frames[0].ndim in (2, 3) and frames[0].dtype != object:
        frames = [frames]
    return [[_grey(image, f"images[{f}][{k}]") for k, image in enumerate(frame)] for f, frame in enumerate(frames)]


def calibrate_targetless(
    rig: Union[Rig, str, os.PathLike],
    images: Any,
    *,
    frames: Optional[Union[str, Tuple[Optional[int], Optional[int], Optional[int]]]] = None,
    estimate: Union[str, Iterable[str]] = ("axis", "distance"),
    huber: float = 1.0,
    max_rms_px: float = 1.0,
    max_sigma_axis_deg: float = 0.1,
    max_sigma_distance_mm: float = 2.0,
    output: Optional[Union[str, os.PathLike]] = None,
) -> TargetlessCalibration:
    """The port(s) of a rig whose cameras are calibrated in air, from frames of any textured scene,
    no board, as ``flatport calibrate --images DIR --rig RIG.json --targetless``
    (docs/targetless.md): matches of the master's corners in every other camera, outliers
    rejected by the ray gap, maximum likelihood over the ports and every match's 3-D point, with σ.

    ``rig`` (a :class:`Rig` or a rig file): the cameras and extrinsics (known) and a guess of the
    port(s), the start (the naive guess is fine: axis on the master's z, 10 mm of air).
    ``images``: a folder holding one sub-folder per rig camera, named as in the rig, of
    synchronized frames (images sorted by name, or one video), as ``flatport stereo`` reads it;
    or the frames themselves: a list of frames, each a list of one image per rig camera in rig
    order (grey float 0 … 1, uint8 or uint16, or colour), or a single frame (a list of images).
    ``frames`` (a folder only): ``"START:STOP:STEP"`` or a ``(start, stop, step)`` tuple; by
    default at most 8 frames spread over the footage. ``estimate`` as :func:`calibrate`'s
    (``axis``, ``distance``, ``layers``, ``extrinsics``; not intrinsics). ``huber``: the robust
    fits' threshold (px); ``max_rms_px``: a fit ending above it tries more starts and is refused.
    The matching and the fit release the GIL.

    Bad input (a missing camera folder, images of the wrong size, too few matches, no fit)
    raises ValueError with the library's message. A parameter the scene does not pin down (an
    axis' σ above ``max_sigma_axis_deg``, an air distance's above ``max_sigma_distance_mm``)
    raises :class:`CalibrationRefused` naming the parameter, its σ and what it trades off with;
    its ``report`` holds the fit and the σ of every parameter, and ``output`` is not written.

    >>> result = flatport.calibrate_targetless("naive.json", "seabed")        # doctest: +SKIP
    >>> result.ports[0]["tilt_deg"], result.ports[0]["axis_std_deg"]        # doctest: +SKIP
    """
    if not isinstance(rig, Rig):
        if not isinstance(rig, (str, os.PathLike)):
            raise TypeError(f"rig must be a flatport.Rig or a path to a rig file, got {type(rig).__name__}")
        rig = load_rig(rig)
    words = [part.strip() for part in (estimate.split(",") if isinstance(estimate, str) else estimate)]
    if isinstance(frames, tuple):
        if len(frames) != 3:
            raise ValueError(f"frames must be (start, stop, step) or 'START:STOP:STEP', got {frames!r}")
        frames = ":".join("" if part is None else str(int(part)) for part in frames)
    if isinstance(images, (str, os.PathLike)):
        folder, arrays = os.fspath(images), None
    else:
        if frames is not None:
            raise ValueError("frames selects frames of a folder; with images given as arrays, pass the frames wanted")
        folder, arrays = None, _targetless_frames(images)
    calibrated, text, refused = _flatport.calibrate_targetless(
        rig._rig, folder, arrays, frames, ",".join(words), float(huber), float(max_rms_px),
        float(max_sigma_axis_deg), float(max_sigma_distance_mm), None if output is None else os.fspath(output),
    )
    report = json.loads(text)
    if refused is not None:
        raise CalibrationRefused(refused, report)
    ports = [dict(p, normal=np.asarray(p["normal"], dtype=np.float64)) for p in report["ports"]]
    return TargetlessCalibration(Rig(calibrated), report, ports, report["rms_px"], report["tracks"])


class Simulation(NamedTuple):
    """What :func:`simulate` made."""

    #: The observations JSON as a dict (what :func:`calibrate` takes).
    observations: dict
    #: The truth: interface, board poses, noise, seed (the CLI's truth.json) as a dict.
    truth: dict


def simulate(
    rig: Rig,
    board: Tuple[int, int, float] = (9, 6, 0.04),
    views: int = 20,
    noise: float = 0.1,
    seed: int = 1,
    cameras: Optional[Sequence[CameraRef]] = None,
    max_board_tilt_deg: float = 45.0,
) -> Simulation:
    """Simulates stereo views of a chessboard through the rig's port, as ``flatport simulate``:
    ``board = (cols, rows, square)`` inner corners and square (metres), random poses both cameras
    see whole, corners projected exactly, Gaussian noise of ``noise`` pixels; equal seeds give
    equal scenes."""
    if not isinstance(rig, Rig):
        raise TypeError(f"rig must be a flatport.Rig, got {type(rig).__name__}")
    cols, rows, square = board
    if cameras is None:
        a, b = 0, 1
    else:
        a, b = (rig._camera_index(c, "cameras") for c in cameras)
    observations, truth = _flatport.simulate(rig._rig, int(cols), int(rows), float(square), int(views), float(noise), int(seed), a, b, float(max_board_tilt_deg))
    return Simulation(json.loads(observations), json.loads(truth))


class SweepResult(NamedTuple):
    """What :func:`sweep` measured."""

    #: Cost per cell, shape (tilt, azimuth) or (tilt, azimuth, distance); inf where a candidate
    #: leaves some corner without an answer.
    cost: np.ndarray
    #: Air layer per cell (the grid's, the profile's least-squares one, or NaN for axis-only costs).
    distance: np.ndarray
    #: The tilt values, degrees.
    tilt_deg: np.ndarray
    #: The azimuth values, degrees.
    azimuth_deg: np.ndarray
    #: cost name and unit, shape, cells, finite cells, seconds, minimum (cell, tilt_deg,
    #: azimuth_deg, distance, cost).
    summary: dict


def sweep(
    rig: Rig,
    observations: Any,
    cost: str = "affine-grid",
    tilt_deg: Tuple[float, float, int] = (0.0, 20.0, 64),
    azimuth_deg: Tuple[float, float, int] = (-180.0, 180.0, 64),
    distance: Optional[Tuple[float, float, int]] = None,
    device: str = "cpu",
    precision: str = "f64",
) -> SweepResult:
    """Sweeps a calibration cost over a grid of axes (and air layers), as ``flatport sweep``:
    grids are ``(start, stop, count)`` with both ends included (numpy's linspace). ``cost`` is
    ``affine-grid``, ``reprojection``, ``scene`` (or ``ray-gap``, ``plane-fitting``,
    ``plane-angles``)."""
    if not isinstance(rig, Rig):
        raise TypeError(f"rig must be a flatport.Rig, got {type(rig).__name__}")
    _check_engine(device, precision)
    grid = lambda g, name: (float(g[0]), float(g[1]), int(g[2])) if g is not None and len(g) == 3 else _bad_grid(name, g)  # noqa: E731
    tilts, azimuths = grid(tilt_deg, "tilt_deg"), grid(azimuth_deg, "azimuth_deg")
    distances = None if distance is None else grid(distance, "distance")
    costs, cell_distances, summary = _flatport.sweep(rig._rig, _json_argument("observations", observations), cost, tilts, azimuths, distances, device, precision)
    return SweepResult(costs, cell_distances, np.linspace(*tilts), np.linspace(*azimuths), json.loads(summary))


def _bad_grid(name: str, value: Any) -> Any:
    raise ValueError(f"{name} must be (start, stop, count), got {value!r}")


class StereoResult(NamedTuple):
    """Depths of the reference camera's pixels, as ``flatport stereo`` writes them: ``depth``
    (H, W) float32, z in the reference camera's frame, NaN where no confident depth; ``points``
    (H, W, 3) float32, master frame; ``confidence`` (H, W) float32, 0 … 1 (0 where NaN);
    ``device`` the device that ran the sweep."""

    depth: np.ndarray
    points: np.ndarray
    confidence: np.ndarray
    device: str


def _grey(image: Any, name: str) -> np.ndarray:
    array = np.asarray(image)
    if array.ndim == 3:
        array = array[..., :3].mean(axis=-1) if array.shape[-1] >= 3 else array[..., 0]
    if array.ndim != 2:
        raise ValueError(f"{name} must be a 2-D grey (or H × W × 3 colour) image, got shape {array.shape}")
    if array.dtype == np.uint8:
        array = array / 255.0
    elif array.dtype == np.uint16:
        array = array / 65535.0
    array = np.ascontiguousarray(array, dtype=np.float32)
    if not np.isfinite(array).all():
        raise ValueError(f"{name} has pixels that are not finite numbers")
    return array


def stereo(
    rig: Rig,
    images: Sequence[Any],
    reference: CameraRef = None,
    depth: Optional[Tuple[float, float]] = None,
    hypotheses: Optional[int] = None,
    window: int = 3,
    min_confidence: float = 0.25,
    device: str = "auto",
) -> StereoResult:
    """Dense refraction-exact stereo, as ``flatport stereo``: one image per rig camera in rig
    order (grey float 0 … 1, uint8 or uint16, or colour), the reference camera (default the
    master), ``depth = (min, max)`` in metres (z in the reference camera's frame; default: found
    from the images by a coarse sweep), ``hypotheses`` uniform in 1/z (default: the step rule,
    one step moves a hypothesis by at most 0.8 px in every voting camera; docs/stereo.md),
    (2·window + 1)² ZNCC windows. ``device``
    ``"cpu"`` (f64), ``"gpu"`` (WGSL kernels, f32; the same depths within a fraction of a
    hypothesis step) or ``"auto"`` (a hardware GPU when there is one). The GPU's pipelines are
    kept between calls, so the frames of a sequence stream through.

    >>> result = flatport.stereo(rig, [left, right], depth=(1.0, 2.2))   # doctest: +SKIP
    >>> np.nanmedian(result.depth)                                       # doctest: +SKIP
    """
    if not isinstance(rig, Rig):
        raise TypeError(f"rig must be a flatport.Rig, got {type(rig).__name__}")
    if device not in _DEVICES:
        raise ValueError(f"device must be one of {_DEVICES}, got {device!r}")
    grey = [_grey(image, f"images[{k}]") for k, image in enumerate(images)]
    index = 0 if reference is None else rig._camera_index(reference, "reference")
    span = None if depth is None else (float(depth[0]), float(depth[1]))
    d, points, confidence, used = _flatport.stereo(
        rig._rig, grey, index, span, None if hypotheses is None else int(hypotheses), int(window), float(min_confidence), device
    )
    return StereoResult(d, points, confidence, used)


class StereoFrame(NamedTuple):
    """One frame of :func:`stereo_frames`: ``name`` (the output folder ``flatport stereo`` gives it:
    the reference image's file name without extension, or ``frame_NNNNNN`` for a video),
    ``index`` (0-based, in the sequence), then ``depth``, ``points``, ``confidence`` and ``device``
    as in :class:`StereoResult`."""

    name: str
    index: int
    depth: np.ndarray
    points: np.ndarray
    confidence: np.ndarray
    device: str


def stereo_frames(
    rig: Rig,
    images: Union[str, "os.PathLike[str]"],
    frames: Union[str, slice, None] = None,
    reference: CameraRef = None,
    depth: Optional[Tuple[float, float]] = None,
    hypotheses: Optional[int] = None,
    window: int = 3,
    min_confidence: float = 0.25,
    device: str = "auto",
) -> Iterator[StereoFrame]:
    """Dense stereo over a sequence, as ``flatport stereo --images DIR --frames FRAMES``: ``images``
    is a folder with one sub-folder per rig camera holding its images (frames paired by sorted
    file name) or one video (MP4/MOV/AVI/MKV, frames paired by index, decoded by the ``ffmpeg``
    tool). ``frames`` selects frames as ``"START:STOP:STEP"`` or a ``slice`` (default every frame).
    The other arguments are those of :func:`stereo`. The folder, the selection and the options are
    checked at once (``ValueError``); the frames are computed as the iterator is advanced, the next
    one while the caller works on the last.

    >>> for frame in flatport.stereo_frames(rig, "footage", frames="0:100:10"):   # doctest: +SKIP
    ...     np.save(f"{frame.name}.npy", frame.depth)
    """
    if not isinstance(rig, Rig):
        raise TypeError(f"rig must be a flatport.Rig, got {type(rig).__name__}")
    if device not in _DEVICES:
        raise ValueError(f"device must be one of {_DEVICES}, got {device!r}")
    if frames is None:
        text = ":"
    elif isinstance(frames, slice):
        parts = [frames.start, frames.stop, frames.step]
        if any(p is not None and (not isinstance(p, int) or p < 0) for p in parts):
            raise ValueError(f"frames must be a slice of non-negative integers, got {frames!r}")
        text = ":".join("" if p is None else str(p) for p in parts)
    elif isinstance(frames, str):
        text = frames
    else:
        raise TypeError(f"frames must be 'START:STOP:STEP', a slice or None, got {type(frames).__name__}")
    index = 0 if reference is None else rig._camera_index(reference, "reference")
    span = None if depth is None else (float(depth[0]), float(depth[1]))
    inner = _flatport.stereo_frames(
        rig._rig, os.fspath(images), text, index, span, None if hypotheses is None else int(hypotheses), int(window), float(min_confidence), device
    )
    return (StereoFrame(*item) for item in inner)
