"""Arrays that live on the GPU: upload once, chain relations on the device, copy back once.

A :class:`DeviceArray` holds rows on the GPU engine of a rig (``device="gpu"``, f32 or f64) and
copies nothing to the host until :meth:`DeviceArray.numpy` is called. The relations here take and
give device arrays, so a chain (matched pixels of two cameras → 3-D points) runs without a copy
between its steps, in one fused kernel (:func:`triangulate_pixels`) or step by step, the rays kept
on the device (:func:`backproject` both cameras' pixels, then :func:`triangulate`)::

    >>> import flatport, flatport.gpu as fg                                   # doctest: +SKIP
    >>> rig = flatport.load_rig("data/example_rig.json")                      # doctest: +SKIP
    >>> left = fg.upload(rig, uv_left, "pixels")                              # doctest: +SKIP
    >>> right = fg.upload(rig, uv_right, "pixels")                            # doctest: +SKIP
    >>> points = fg.triangulate_pixels(rig, left, right, ("left", "right"))   # doctest: +SKIP
    >>> same = fg.triangulate(fg.backproject(rig, left, "left"),
    ...                       fg.backproject(rig, right, "right"))            # doctest: +SKIP
    >>> xyzr = points.numpy()                                                 # doctest: +SKIP

Kinds and their columns: ``pixels`` (u, v), ``points`` (x, y, z), ``rays`` (ox, oy, oz, dx, dy,
dz), ``triangulated`` (x, y, z, residual). A row without an answer keeps its status through the
chain and reads back as NaN (:data:`flatport.STATUS`).
"""

from __future__ import annotations

from typing import Any, List, Optional, Sequence, Tuple

import numpy as np

_KINDS = {"pixels": 2, "points": 3, "rays": 6}


class DeviceArray:
    """Rows on the GPU (made by :func:`upload`, :func:`pixel_grid` or a relation here)."""

    __slots__ = ("_array", "_rig")

    def __init__(self, array: Any, rig: Any) -> None:
        self._array = array
        self._rig = rig

    @property
    def kind(self) -> str:
        """``pixels``, ``points``, ``rays`` or ``triangulated``."""
        return self._array.kind

    @property
    def shape(self) -> Tuple[int, int]:
        """(N, width) of the rows."""
        return (len(self._array), self._array.width)

    @property
    def precision(self) -> str:
        """``f32`` or ``f64``: the reals on the device."""
        return self._array.precision

    def __len__(self) -> int:
        return len(self._array)

    def numpy(self) -> np.ndarray:
        """The rows copied to the host: (N, width) float64, NaN where :meth:`status` is not 0."""
        return self._array.read()[0]

    def status(self) -> np.ndarray:
        """The (N,) uint32 status of the rows (0: an answer; else a :data:`flatport.STATUS` code)."""
        return self._array.read()[1]

    def read(self) -> Tuple[np.ndarray, np.ndarray]:
        """``(rows, status)`` in one copy, as the host-row relations return them."""
        return self._array.read()

    def __repr__(self) -> str:
        return f"DeviceArray(kind={self.kind!r}, shape={self.shape}, precision={self.precision!r})"


def _check(name: str, value: Any, kind: str) -> DeviceArray:
    if not isinstance(value, DeviceArray):
        raise TypeError(f"{name} must be a flatport.gpu.DeviceArray of {kind}, got {type(value).__name__}")
    return value


def upload(rig: Any, rows: Any, kind: str, precision: str = "f32") -> DeviceArray:
    """Copies (N, width) rows of ``kind`` (``pixels``, ``points`` or ``rays``) to the GPU of
    ``rig`` in ``precision``: the one copy to the device."""
    from . import _rows

    if kind not in _KINDS:
        raise ValueError(f"kind must be one of {tuple(_KINDS)}, got {kind!r}")
    if precision not in ("f32", "f64"):
        raise ValueError(f"precision must be 'f32' or 'f64', got {precision!r}")
    array = rig._rig.upload_rows(_rows(kind, rows, _KINDS[kind]), kind, precision)
    return DeviceArray(array, rig)


def pixel_grid(rig: Any, width: int, height: int, step: int = 1, precision: str = "f32") -> DeviceArray:
    """The pixels of a ``width`` × ``height`` grid every ``step`` pixels, made on the GPU,
    row-major: row i is (u, v) = step · (i mod width, i div width)."""
    if precision not in ("f32", "f64"):
        raise ValueError(f"precision must be 'f32' or 'f64', got {precision!r}")
    return DeviceArray(rig._rig.pixel_grid_rows(int(width), int(height), int(step), precision), rig)


def backproject(rig: Any, pixels: DeviceArray, camera: Any = None) -> DeviceArray:
    """Rays in the water (device ``rays``) of device ``pixels`` of ``camera``."""
    pixels = _check("pixels", pixels, "pixels")
    return DeviceArray(rig._rig.backproject_rows(pixels._array, rig._camera_index(camera, "camera")), rig)


def project(rig: Any, points: DeviceArray, cameras: Optional[Sequence[Any]] = None) -> List[DeviceArray]:
    """Device ``pixels`` of device ``points`` in each of ``cameras`` (default: every camera of
    the rig), the points read once."""
    points = _check("points", points, "points")
    if cameras is None:
        indices = list(range(len(rig.camera_names)))
    else:
        if isinstance(cameras, (str, int)):
            raise ValueError(f"cameras must be a sequence of names or indices, got {cameras!r}")
        indices = [rig._camera_index(c, f"cameras[{k}]") for k, c in enumerate(cameras)]
    return [DeviceArray(a, rig) for a in rig._rig.project_rows(points._array, indices)]


def triangulate(rays_a: DeviceArray, rays_b: DeviceArray) -> DeviceArray:
    """Device ``triangulated`` rows (x, y, z, residual) of device rays of two cameras, row i of
    ``rays_a`` with row i of ``rays_b``."""
    rays_a = _check("rays_a", rays_a, "rays")
    rays_b = _check("rays_b", rays_b, "rays")
    return DeviceArray(rays_a._rig._rig.triangulate_rows(rays_a._array, rays_b._array), rays_a._rig)


def triangulate_pixels(rig: Any, pixels_a: DeviceArray, pixels_b: DeviceArray, cameras: Optional[Sequence[Any]] = None) -> DeviceArray:
    """Device ``triangulated`` rows (x, y, z, residual) of matched device pixels, row i of
    ``pixels_a`` (raw pixels of camera ``cameras[0]``) with row i of ``pixels_b`` (``cameras[1]``;
    default the rig's first two cameras), in one fused kernel: both back-projections and the
    triangulation in one pass, no rays on the device between. The rows of
    ``triangulate(backproject(rig, pixels_a, a), backproject(rig, pixels_b, b))`` and the statuses
    of ``rig.triangulate`` on the same matches."""
    pixels_a = _check("pixels_a", pixels_a, "pixels")
    pixels_b = _check("pixels_b", pixels_b, "pixels")
    a, b = rig._camera_pair(cameras)
    return DeviceArray(rig._rig.triangulate_pixels_rows(pixels_a._array, pixels_b._array, a, b), rig)
