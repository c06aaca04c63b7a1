"""Projection, back-projection, triangulation and VOPs through numpy, against the independent
numpy tracer in _oracle.py and against the CLI."""

import csv
import json
import os
import pathlib
import shutil
import subprocess

import numpy as np
import pytest

import flatport
import _oracle

ROOT = pathlib.Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "data" / "example_rig.json"


@pytest.fixture(scope="module")
def rig():
    return flatport.load_rig(EXAMPLE)


@pytest.fixture(scope="module")
def oracle():
    return _oracle.OracleRig(json.loads(EXAMPLE.read_text()))


def points_in_view(n, seed):
    """Points in the water in front of both cameras (0.4 to 3 m away, within ~30° of the axis)."""
    rng = np.random.default_rng(seed)
    z = rng.uniform(0.4, 3.0, n)
    return np.stack([rng.uniform(-0.5, 0.5, n) * z, rng.uniform(-0.4, 0.4, n) * z, z], axis=1)


def test_project_matches_the_brute_force_tracer_within_1e_6_px(rig, oracle):
    points = points_in_view(2000, seed=11)
    for k, name in enumerate(rig.camera_names):
        uv, status = rig.project(points, camera=name)
        assert uv.shape == (2000, 2) and uv.dtype == np.float64
        assert status.shape == (2000,) and status.dtype == np.uint32
        assert (status == 0).all()
        # The oracle's bisection runs to machine precision of the angle; 1e-6 px is the bound.
        assert np.abs(uv - _oracle.project(oracle, k, points)).max() < 1e-6


def test_backproject_matches_the_brute_force_tracer(rig, oracle):
    rng = np.random.default_rng(12)
    pixels = np.stack([rng.uniform(0, 1279, 3000), rng.uniform(0, 1023, 3000)], axis=1)
    for k in range(2):
        rays, status = rig.backproject(pixels, camera=k)
        assert rays.shape == (3000, 6) and (status == 0).all()
        expected = _oracle.backproject(oracle, k, pixels)
        # Origins in metres and unit directions: the tracer's own rounding is ~1e-15.
        assert np.abs(rays - expected).max() < 1e-12


def test_project_then_triangulate_returns_the_points(rig, oracle):
    points = points_in_view(2000, seed=13)
    uv_l, s_l = rig.project(points, camera="left")
    uv_r, s_r = rig.project(points, camera="right")
    xyzr, status = rig.triangulate(np.hstack([uv_l, uv_r]), cameras=("left", "right"))
    assert (s_l == 0).all() and (s_r == 0).all() and (status == 0).all()
    assert xyzr.shape == (2000, 4)
    assert np.abs(xyzr[:, :3] - points).max() < 1e-9
    assert xyzr[:, 3].max() < 1e-9
    # The oracle's own triangulation of the oracle's pixels agrees too.
    expected = _oracle.closest_midpoint(_oracle.backproject(oracle, 0, uv_l), _oracle.backproject(oracle, 1, uv_r))
    assert np.abs(xyzr[:, :3] - expected[:, :3]).max() < 1e-9


def test_vop_rows(rig):
    vops, status = rig.vop(points_in_view(100, seed=14))
    assert vops.shape == (100, 6) and (status == 0).all()
    assert (vops[:, 0] > 0).all() and (vops[:, 5] >= 0).all()


def test_rows_without_an_answer_are_nan_with_their_code(rig):
    # In the air between camera and port, behind the camera, a coordinate beyond 1e300.
    points = np.array([[0.0, 0.0, 0.01], [0.0, 0.0, -1.0], [0.0, 0.0, 1e301], [0.1, 0.1, 1.0]])
    uv, status = rig.project(points)
    assert list(status[:3]) == [4, 4, 8] or (status[:3] != 0).all()
    assert np.isnan(uv[:3]).all() and status[3] == 0 and np.isfinite(uv[3]).all()
    assert set(int(s) for s in status) <= set(flatport.STATUS)


def test_a_million_points_go_through_in_one_call(rig):
    points = points_in_view(1_000_000, seed=15)
    uv, status = rig.project(points, camera="right")
    assert uv.shape == (1_000_000, 2) and (status == 0).all()
    rays, status = rig.backproject(uv, camera="right")
    assert rays.shape == (1_000_000, 6) and (status == 0).all()


def test_float32_and_lists_are_taken_float64_c_contiguous_is_not_copied(rig):
    points = points_in_view(50, seed=16)
    uv64, _ = rig.project(points)
    uv32, _ = rig.project(points.astype(np.float32))
    assert np.abs(uv32 - rig.project(points.astype(np.float32).astype(np.float64))[0]).max() == 0
    assert np.abs(uv64 - rig.project(points.tolist())[0]).max() == 0
    # Fortran order and strided views are converted, not refused.
    assert np.abs(rig.project(np.asfortranarray(points))[0] - uv64).max() == 0
    assert np.abs(rig.project(np.hstack([points, points])[:, :3])[0] - uv64).max() == 0
    # The C-contiguous float64 path hands the caller's buffer to Rust (no copy).
    assert flatport._rows("points", points, 3) is points


def test_wrong_shapes_and_dtypes_raise_naming_the_argument(rig):
    with pytest.raises(ValueError, match="points must have shape \\(N, 3\\)"):
        rig.project(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="points"):
        rig.project(np.zeros(3))
    with pytest.raises(TypeError, match="points must be a float array"):
        rig.project(np.zeros((4, 3), dtype=np.int64))
    with pytest.raises(ValueError, match="pixels must have shape \\(N, 2\\)"):
        rig.backproject(np.zeros((4, 3)))
    with pytest.raises(TypeError, match="pixels"):
        rig.backproject(np.array([["a", "b"]]))
    with pytest.raises(ValueError, match="matches must have shape \\(N, 4\\)"):
        rig.triangulate(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="camera='middle'"):
        rig.project(np.zeros((1, 3)), camera="middle")
    with pytest.raises(ValueError, match="device"):
        rig.project(np.zeros((1, 3)), device="tpu")
    with pytest.raises(ValueError, match="CPU path is f64 only"):
        rig.project(np.zeros((1, 3)), precision="f32")


def test_empty_batches(rig):
    uv, status = rig.project(np.zeros((0, 3)))
    assert uv.shape == (0, 2) and status.shape == (0,)


def test_dict_round_trip_names_and_ports(rig):
    d = rig.to_dict()
    again = flatport.Rig.from_dict(d).to_dict()
    # Rotations are held as unit quaternions: a matrix read back moves by an ulp.
    for a, b in zip(again["cameras"], d["cameras"]):
        assert np.abs(np.array(a.pop("rotation", np.eye(3))) - np.array(b.pop("rotation", np.eye(3)))).max() < 1e-15
    assert again == d
    d = rig.to_dict()
    assert rig.camera_names == ["left", "right"]
    assert rig.cameras[1]["translation"] == [-0.06, 0.0, 0.0]
    n = np.array(rig.interface["normal"])
    assert abs(np.linalg.norm(n) - 1) < 1e-15
    port = rig.port("right")
    R = np.array(rig.cameras[1]["rotation"])
    assert np.abs(np.array(port["normal"]) - R @ n).max() < 1e-15
    assert abs(port["distance"] - (rig.interface["distance"] - n @ np.array(port["centre"]))) < 1e-15
    bad = dict(d, interface=dict(d["interface"], normall=[0, 0, 1]))
    with pytest.raises(ValueError, match="normall"):
        flatport.Rig.from_dict(bad)


def flatport_binary():
    for candidate in [os.environ.get("FLATPORT_BIN"), ROOT / "target" / "release" / "flatport", shutil.which("flatport")]:
        if candidate and pathlib.Path(candidate).is_file():
            return str(candidate)
    return None


@pytest.mark.skipif(flatport_binary() is None, reason="no flatport binary (set FLATPORT_BIN or build target/release/flatport)")
def test_equal_to_the_cli(rig, tmp_path):
    points = points_in_view(500, seed=17)
    points[0] = [0.0, 0.0, 0.01]  # a NaN row
    path = tmp_path / "points.csv"
    with open(path, "w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(["x", "y", "z"])
        writer.writerows(points.tolist())
    out = tmp_path / "pixels.csv"
    subprocess.run([flatport_binary(), "project", "--rig", str(EXAMPLE), "--points", str(path), "--camera", "right", "--device", "cpu", "-o", str(out)], check=True, capture_output=True)
    cli = np.genfromtxt(out, delimiter=",", skip_header=1)
    uv, status = rig.project(points, camera="right")
    assert status[0] != 0 and np.isnan(cli[0]).all()
    # The CLI writes shortest round-trip decimals: equal bits.
    np.testing.assert_array_equal(uv, cli)


def test_compute_releases_the_gil(rig):
    import threading
    import time

    points = points_in_view(2_000_000, seed=18)
    timing = {}

    def work():
        timing["start"] = time.perf_counter()
        timing["result"] = rig.project(points, camera="right")
        timing["end"] = time.perf_counter()

    worker = threading.Thread(target=work)
    worker.start()
    # The longest the main thread waited between two steps: with the GIL held through the call,
    # it would be the whole call.
    longest, last = 0.0, time.perf_counter()
    while worker.is_alive():
        now = time.perf_counter()
        longest, last = max(longest, now - last), now
    worker.join()
    assert (timing["result"][1] == 0).all()
    call = timing["end"] - timing["start"]
    assert longest < call / 2, (longest, call)
