"""AquaCal interop checked by AquaCal's own code (PyPI aquacal 2.1): `flatport export aquacal`
read by AquaCal's `load_calibration` and projected / back-projected with AquaCal's refractive
geometry (`refractive_project`, `refractive_back_project`, built as its own
`validation/reprojection.py` builds them), against `flatport project` / `backproject` on the same
rig; and the reverse: a calibration AquaCal's `save_calibration` writes, read by
`flatport rig from-aquacal`. Uses the CLI only, so it runs without the Python binding.

scripts/test.sh installs aquacal 2.1.0 (--no-deps: it pins opencv-python, which would clash with
the suite's opencv-python-headless; its other dependencies are installed by name). Skipped where
`aquacal` cannot be imported. On its own:
  python3 -m venv target/venv && target/venv/bin/pip install aquacal==2.1.0 pytest
  FLATPORT_BIN=target/release/flatport target/venv/bin/python -m pytest python/tests/test_aquacal.py
"""

import csv
import json
import os
import pathlib
import shutil
import subprocess

import numpy as np
import pytest

aquacal = pytest.importorskip("aquacal", reason="aquacal (PyPI) is not installed: AquaCal's own loader and projection are not at hand")
import cv2  # noqa: E402  (aquacal's dependency)
from aquacal.config.schema import (  # noqa: E402
    BoardConfig,
    CalibrationMetadata,
    CalibrationResult,
    CameraCalibration,
    CameraExtrinsics,
    CameraIntrinsics,
    DiagnosticsData,
    InterfaceParams,
)
from aquacal.core.camera import Camera  # noqa: E402
from aquacal.core.interface_model import Interface  # noqa: E402
from aquacal.core.refractive_geometry import refractive_back_project, refractive_project  # noqa: E402
from aquacal.io.serialization import load_calibration, save_calibration  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[2]


def flatport_binary():
    for candidate in [os.environ.get("FLATPORT_BIN"), ROOT / "target" / "release" / "flatport", shutil.which("flatport")]:
        if candidate and pathlib.Path(candidate).is_file():
            return str(candidate)
    return None


pytestmark = pytest.mark.skipif(flatport_binary() is None, reason="no flatport binary (set FLATPORT_BIN or build target/release/flatport)")

# A tilted surface, three cameras with distortion and rotated extrinsics (rig file, DESIGN.md §1).
RIG = {
    "cameras": [
        {"name": "a", "width": 1280, "height": 1024, "fx": 864.91, "fy": 865.5, "cx": 640.25, "cy": 511.75, "distortion": [-0.1, 0.01, 0.0005, -0.0025, 0.001]},
        {"name": "b", "width": 1920, "height": 1080, "fx": 1400, "fy": 1401, "cx": 960, "cy": 540,
         "rotation": [[0.9998468789078377, -0.017499106784510807, 0.0], [0.017499106784510807, 0.9998468789078377, 0.0], [0.0, 0.0, 1.0]], "translation": [-0.06, 0.001, 0.002]},
        {"name": "c", "width": 640, "height": 480, "fx": 500, "fy": 500, "cx": 320, "cy": 240, "distortion": [0.05, -0.01, 0.0, 0.0, 0.0],
         "rotation": [[0.9950041652780258, 0.0, 0.09983341664682815], [0.0, 1.0, 0.0], [-0.09983341664682815, 0.0, 0.9950041652780258]], "translation": [0.03, -0.08, 0.01]},
    ],
    "interface": {"normal": [0.12, -0.07, 1.0], "distance": 0.043, "index_air": 1.0003, "index_water": 1.341},
}


def write_csv(path, header, rows):
    with open(path, "w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(header)
        writer.writerows(np.asarray(rows).tolist())


def run(*args):
    subprocess.run([flatport_binary(), *map(str, args)], check=True, capture_output=True)


def flatport_project(rig_path, camera, points, tmp_path):
    write_csv(tmp_path / "points.csv", ["x", "y", "z"], points)
    run("project", "--rig", rig_path, "--points", tmp_path / "points.csv", "--camera", camera, "--device", "cpu", "-o", tmp_path / "pixels.csv")
    return np.genfromtxt(tmp_path / "pixels.csv", delimiter=",", skip_header=1).reshape(-1, 2)


def flatport_backproject(rig_path, camera, pixels, tmp_path):
    write_csv(tmp_path / "pixels.csv", ["u", "v"], pixels)
    run("backproject", "--rig", rig_path, "--pixels", tmp_path / "pixels.csv", "--camera", camera, "--device", "cpu", "-o", tmp_path / "rays.csv")
    return np.genfromtxt(tmp_path / "rays.csv", delimiter=",", skip_header=1).reshape(-1, 6)


def aquacal_views(calibration):
    """Camera and Interface per camera, as AquaCal's validation/reprojection.py builds them."""
    views = {}
    for name, cam in calibration.cameras.items():
        camera = Camera(name, cam.intrinsics, cam.extrinsics)
        interface = Interface(normal=calibration.interface.normal, camera_distances={name: cam.water_z}, n_air=calibration.interface.n_air, n_water=calibration.interface.n_water)
        views[name] = (camera, interface)
    return views


def aquacal_project(view, points_world):
    camera, interface = view
    # Newton on the surface point to 1e-14 m (its default stops at 1e-9 m, ~1e-5 px here).
    out = [refractive_project(camera, interface, p, max_iterations=100, tolerance=1e-14) for p in points_world]
    return np.array([[np.nan, np.nan] if p is None else p for p in out])


def points_in_view(n, seed):
    rng = np.random.default_rng(seed)
    z = rng.uniform(0.3, 2.5, n)
    return np.stack([rng.uniform(-0.35, 0.35, n) * z, rng.uniform(-0.25, 0.25, n) * z, z], axis=1)


def test_aquacal_loads_our_export_and_projects_as_flatport_does(tmp_path):
    rig_path = tmp_path / "rig.json"
    rig_path.write_text(json.dumps(RIG))
    out = tmp_path / "calibration.json"
    run("export", "aquacal", "--rig", rig_path, "-o", out)
    calibration = load_calibration(out)
    assert list(calibration.cameras) == ["a", "b", "c"]
    np.testing.assert_array_equal(calibration.interface.normal, [0, 0, -1])
    assert (calibration.interface.n_air, calibration.interface.n_water) == (1.0003, 1.341)
    # AquaCal's world: X_master = R_a X_world (the master's extrinsics, t = 0).
    master_from_world = calibration.cameras["a"].extrinsics.R
    np.testing.assert_array_equal(calibration.cameras["a"].extrinsics.t, [0, 0, 0])
    views = aquacal_views(calibration)
    points = points_in_view(60, seed=3)
    points_world = points @ master_from_world  # rows: R^T X
    for name in ["a", "b", "c"]:
        ours = flatport_project(rig_path, name, points, tmp_path)
        theirs = aquacal_project(views[name], points_world)
        seen = ~np.isnan(ours).any(axis=1)
        assert seen.sum() > 40, name
        np.testing.assert_array_equal(np.isnan(theirs).any(axis=1), ~seen)
        # Both solve the same refraction in f64 (measured: 2e-12 px); AquaCal's
        # cv2.projectPoints then distorts as flatport does.
        assert np.abs(ours[seen] - theirs[seen]).max() < 1e-9, name

        pixels = ours[seen][:20]
        rays = flatport_backproject(rig_path, name, pixels, tmp_path)
        for pixel, ray in zip(pixels, rays):
            origin, direction = refractive_back_project(views[name][0], views[name][1], pixel)
            # AquaCal undistorts with cv2.undistortPoints' fixed-point iteration, so its ray is as
            # good as that inversion (measured: 6e-10 with distortion, 1e-16 without).
            np.testing.assert_allclose(master_from_world @ origin, ray[:3], rtol=0, atol=1e-8)
            np.testing.assert_allclose(master_from_world @ direction, ray[3:], rtol=0, atol=1e-8)


def test_flatport_reads_what_aquacal_writes(tmp_path):
    rvec = np.array([0.06, -0.04, 0.0])  # AquaCal's reference-camera tilt (rx, ry, 0)
    R0, _ = cv2.Rodrigues(rvec)
    R1, _ = cv2.Rodrigues(np.array([0.01, 0.02, -0.03]))
    C1 = np.array([0.12, -0.02, 0.005])
    K0 = np.array([[1000.0, 0.0, 640.0], [0.0, 1002.0, 480.0], [0.0, 0.0, 1.0]])
    K1 = np.array([[950.0, 0.0, 630.0], [0.0, 951.0, 470.0], [0.0, 0.0, 1.0]])
    cameras = {
        "cam0": CameraCalibration("cam0", CameraIntrinsics(K0, np.array([-0.05, 0.01, 0.0, 0.0, 0.0]), (1280, 960)), CameraExtrinsics(R0, np.zeros(3)), water_z=0.3),
        "cam1": CameraCalibration("cam1", CameraIntrinsics(K1, np.zeros(5), (1280, 960)), CameraExtrinsics(R1, -R1 @ C1), water_z=0.3),
    }
    result = CalibrationResult(
        cameras=cameras,
        interface=InterfaceParams(normal=np.array([0.0, 0.0, -1.0]), n_air=1.0, n_water=1.333),
        board=BoardConfig(7, 5, 0.04, 0.03, "DICT_4X4_50"),
        diagnostics=DiagnosticsData(0.3, {"cam0": 0.3, "cam1": 0.3}, 0.001, 0.0005),
        metadata=CalibrationMetadata("2026-12-05", "2.1.0", "x", 10, 2),
    )
    path = tmp_path / "calibration.json"
    save_calibration(result, path)
    rig_path = tmp_path / "rig.json"
    run("rig", "from-aquacal", path, "-o", rig_path)
    rig = json.loads(rig_path.read_text())
    # The surface seen from the tilted reference camera: n = R0 (0, 0, 1), d = water_z.
    n = np.array(rig["interface"]["normal"])
    np.testing.assert_allclose(n / np.linalg.norm(n), R0[:, 2], atol=1e-15)
    assert abs(rig["interface"]["distance"] - 0.3) < 1e-15
    views = aquacal_views(load_calibration(path))
    rng = np.random.default_rng(5)
    points_world = np.stack([rng.uniform(-0.4, 0.5, 50), rng.uniform(-0.3, 0.3, 50), rng.uniform(0.5, 2.0, 50)], axis=1)
    points_master = points_world @ R0.T  # X_master = R0 X_world
    for name in ["cam0", "cam1"]:
        ours = flatport_project(rig_path, name, points_master, tmp_path)
        theirs = aquacal_project(views[name], points_world)
        assert not np.isnan(ours).any() and not np.isnan(theirs).any()
        assert np.abs(ours - theirs).max() < 1e-9, name
