"""The GPU kernels through Python (lavapipe without a GPU): the same rows as the CPU within
DESIGN.md §5's tolerances, and the engine kept per rig. Skipped where there is no Vulkan adapter,
except under CI, where that is a failure (as the Rust GPU tests)."""

import os

import numpy as np
import pytest

import flatport
from test_geometry import EXAMPLE, points_in_view


@pytest.fixture(scope="module")
def rig():
    rig = flatport.load_rig(EXAMPLE)
    try:
        rig.engine("gpu", "f32")
    except RuntimeError as error:
        if os.environ.get("CI"):
            raise
        pytest.skip(f"no Vulkan adapter: {error}")
    return rig


def close(gpu, cpu, bound):
    """|gpu − cpu| ≤ bound · max(1, |cpu|) wherever the CPU has an answer."""
    ok = np.isfinite(cpu).all(axis=-1)
    return np.abs(gpu[ok] - cpu[ok]).max() <= bound * np.maximum(1, np.abs(cpu[ok])).max()


def test_gpu_rows_agree_with_the_cpu(rig):
    points = points_in_view(20000, seed=41)
    uv, status = rig.project(points, camera="right")
    uv32, status32 = rig.project(points, camera="right", device="gpu", precision="f32")
    assert (status32 == status).all() and np.abs(uv32 - uv).max() < 1e-3
    rays, _ = rig.backproject(uv, camera="right")
    rays32, _ = rig.backproject(uv, camera="right", device="gpu", precision="f32")
    assert np.abs(rays32[:, 3:] - rays[:, 3:]).max() < 2e-6
    try:
        uv64, status64 = rig.project(points, camera="right", device="gpu", precision="f64")
    except RuntimeError as error:
        pytest.skip(f"the adapter has no f64: {error}")
    assert (status64 == status).all() and close(uv64, uv, 1e-12)
    rays64, _ = rig.backproject(uv, camera="right", device="gpu", precision="f64")
    assert close(rays64, rays, 1e-12)


def test_gpu_raymap_from_the_shader_grid(rig):
    cpu, cpu_status = rig.raymap(camera="left")
    try:
        gpu, gpu_status = rig.raymap(camera="left", device="gpu", precision="f64")
    except RuntimeError as error:
        pytest.skip(f"the adapter has no f64: {error}")
    assert (gpu_status == cpu_status).all()
    assert close(gpu.reshape(-1, 6), cpu.reshape(-1, 6), 1e-12)


def test_the_engine_is_kept_per_rig(rig):
    first = rig._rig.engine_id("gpu", "f32")
    rig.project(points_in_view(10, seed=42), device="gpu", precision="f32")
    assert rig._rig.engine_id("gpu", "f32") == first
    assert rig._rig.engine_id("cpu", "f64") != first
    assert rig._rig.engine_id("cpu", "f64") == rig._rig.engine_id("cpu", "f64")


def test_calibrate_and_sweep_on_the_gpu_agree_with_the_cpu(rig):
    simulation = flatport.simulate(rig, views=8, noise=0.1, seed=3)
    d = rig.to_dict()
    d["interface"]["normal"], d["interface"]["distance"] = [0.0, 0.0, 1.0], 0.01
    start = flatport.Rig.from_dict(d)
    try:
        gpu = flatport.calibrate(start, simulation.observations, method="simultaneous", device="gpu")
    except RuntimeError as error:
        pytest.skip(f"the adapter has no f64: {error}")
    cpu = flatport.calibrate(start, simulation.observations, method="simultaneous", device="cpu")
    assert gpu.report["backend"].startswith("gpu")
    assert np.abs(np.array(gpu.rig.interface["normal"]) - np.array(cpu.rig.interface["normal"])).max() < 1e-9
    assert abs(gpu.rig.interface["distance"] - cpu.rig.interface["distance"]) < 1e-9
    grid = dict(cost="reprojection", tilt_deg=(6, 10, 5), azimuth_deg=(40, 50, 5))
    on_gpu = flatport.sweep(start, simulation.observations, device="gpu", precision="f64", **grid)
    on_cpu = flatport.sweep(start, simulation.observations, **grid)
    finite = np.isfinite(on_cpu.cost)
    assert (np.isfinite(on_gpu.cost) == finite).all() and finite.any()
    assert np.abs(on_gpu.cost[finite] - on_cpu.cost[finite]).max() <= 1e-9 * np.abs(on_cpu.cost[finite]).max()


def matches_in_view(rig, n, seed):
    """Pixels of the same points in the left and right cameras (rows both see)."""
    points = points_in_view(n, seed=seed)
    left, left_status = rig.project(points, camera="left")
    right, right_status = rig.project(points, camera="right")
    seen = (left_status == 0) & (right_status == 0)
    return left[seen], right[seen]


def test_device_arrays_round_trip_without_change(rig):
    pixels = np.array([[0.0, 0.0], [640.5, 512.25], [1279.0, 1023.0]])
    on_device = flatport.gpu.upload(rig, pixels, "pixels", precision="f32")
    assert on_device.kind == "pixels" and on_device.shape == (3, 2) and on_device.precision == "f32"
    back, status = on_device.read()
    assert (status == 0).all()
    assert (back == pixels).all()  # exact in f32
    grid = flatport.gpu.pixel_grid(rig, 5, 3, step=2)
    expected = np.array([[2 * (i % 5), 2 * (i // 5)] for i in range(15)], dtype=np.float64)
    assert (grid.numpy() == expected).all() and (grid.status() == 0).all()
    with pytest.raises(ValueError):
        flatport.gpu.upload(rig, pixels, "matches")
    with pytest.raises(ValueError):
        flatport.gpu.upload(rig, np.zeros((3, 3)), "pixels")


@pytest.mark.parametrize("precision, bound", [("f32", None), ("f64", 1e-9)])
def test_device_chain_backproject_triangulate_matches_the_cpu(rig, precision, bound):
    left, right = matches_in_view(rig, 5000, seed=43)
    left = np.vstack([left, [[np.nan, 1.0]]])  # a row without an answer keeps its status
    right = np.vstack([right, [[600.0, 500.0]]])
    try:
        on_left = flatport.gpu.upload(rig, left, "pixels", precision=precision)
    except RuntimeError as error:
        pytest.skip(f"the adapter has no {precision}: {error}")
    on_right = flatport.gpu.upload(rig, right, "pixels", precision=precision)
    rays_left = rig.backproject(on_left, camera="left")  # a device array: no copy
    rays_right = flatport.gpu.backproject(rig, on_right, "right")
    assert isinstance(rays_left, flatport.gpu.DeviceArray) and rays_left.kind == "rays"
    points = flatport.gpu.triangulate(rays_left, rays_right)
    xyzr, status = points.read()
    cpu, cpu_status = rig.triangulate(np.hstack([left, right]), cameras=("left", "right"))
    host, host_status = rig.triangulate(np.hstack([left, right]), cameras=("left", "right"), device="gpu", precision=precision)
    assert status[-1] == cpu_status[-1] == 8 and np.isnan(xyzr[-1]).all()
    assert (status == cpu_status).all() and (status == host_status).all()
    ok = status == 0
    assert ok.sum() > 4000
    if bound is None:
        # f32: the rays within 2e-6 rad and 2e-6 m (DESIGN.md §5, tests/gpu.rs) move the midpoint by
        # at most 2 (2e-6 · range + 2e-6) / sin θ; here a bound per row from the CPU's own rays.
        rays_l, _ = rig.backproject(left[ok], camera="left")
        rays_r, _ = rig.backproject(right[ok], camera="right")
        sin = np.linalg.norm(np.cross(rays_l[:, 3:], rays_r[:, 3:]), axis=1)
        ranges = np.linalg.norm(cpu[ok, :3] - rays_l[:, :3], axis=1) + np.linalg.norm(cpu[ok, :3] - rays_r[:, :3], axis=1)
        row_bound = 2 * (2e-6 * ranges + 2 * 2e-6) / sin
        assert (np.abs(xyzr[ok] - cpu[ok]).max(axis=1) < row_bound).all()
        assert (np.abs(xyzr[ok] - host[ok]).max(axis=1) < row_bound).all()
    else:
        assert close(xyzr, cpu, bound) and close(xyzr, host, bound)


@pytest.mark.parametrize("precision", ["f32", "f64"])
def test_fused_device_chain_matches_the_cpu_and_the_three_kernel_chain(rig, precision):
    left, right = matches_in_view(rig, 5000, seed=47)
    # Rows without an answer: pixel a NaN (out of range), pixel b NaN with pixel a far outside the
    # image (out of range, whatever a's back-projection gives: the CPU's order).
    left = np.vstack([left, [[np.nan, 1.0], [-3e5, 2e5]]])
    right = np.vstack([right, [[600.0, 500.0], [np.nan, 500.0]]])
    try:
        on_left = flatport.gpu.upload(rig, left, "pixels", precision=precision)
    except RuntimeError as error:
        pytest.skip(f"the adapter has no {precision}: {error}")
    on_right = flatport.gpu.upload(rig, right, "pixels", precision=precision)
    points = flatport.gpu.triangulate_pixels(rig, on_left, on_right, ("left", "right"))
    assert isinstance(points, flatport.gpu.DeviceArray) and points.kind == "triangulated"
    assert points.shape == (len(left), 4) and points.precision == precision
    xyzr, status = points.read()
    cpu, cpu_status = rig.triangulate(np.hstack([left, right]), cameras=("left", "right"))
    chained, chained_status = flatport.gpu.triangulate(
        flatport.gpu.backproject(rig, on_left, "left"), flatport.gpu.backproject(rig, on_right, "right")
    ).read()
    assert status[-2] == status[-1] == cpu_status[-1] == 8 and np.isnan(xyzr[-2:]).all()
    assert (status == cpu_status).all() and (status[:-1] == chained_status[:-1]).all()
    ok = status == 0
    assert ok.sum() > 4000
    # The rays within 2e-6 (f32) or 1e-12 (f64) rad and relative (DESIGN.md §5) move the midpoint
    # by at most 2 δ (range + 2) / sin θ: a bound per row from the CPU's own rays.
    delta = 2e-6 if precision == "f32" else 1e-12
    rays_l, _ = rig.backproject(left[ok], camera="left")
    rays_r, _ = rig.backproject(right[ok], camera="right")
    sin = np.linalg.norm(np.cross(rays_l[:, 3:], rays_r[:, 3:]), axis=1)
    ranges = np.linalg.norm(cpu[ok, :3] - rays_l[:, :3], axis=1) + np.linalg.norm(cpu[ok, :3] - rays_r[:, :3], axis=1)
    row_bound = 2 * delta * (ranges + 2) / sin
    assert (np.abs(xyzr[ok] - cpu[ok]).max(axis=1) < row_bound).all()
    assert (np.abs(xyzr[ok] - chained[ok]).max(axis=1) < row_bound).all()
    two = flatport.gpu.upload(rig, [[1.0, 2.0]] * 2, "pixels", precision=precision)
    one = flatport.gpu.upload(rig, [[1.0, 2.0]], "pixels", precision=precision)
    with pytest.raises(ValueError, match="2 rows a, 1 rows b"):
        flatport.gpu.triangulate_pixels(rig, two, one)
    with pytest.raises(ValueError, match="takes two arrays of pixels, got rays"):
        flatport.gpu.triangulate_pixels(rig, flatport.gpu.backproject(rig, on_left, "left"), on_right)
    with pytest.raises(TypeError, match="DeviceArray"):
        flatport.gpu.triangulate_pixels(rig, left, on_right)


def test_device_project_into_many_cameras_matches_the_cpu(rig):
    points = points_in_view(4000, seed=44)
    on_device = flatport.gpu.upload(rig, points, "points")
    both = flatport.gpu.project(rig, on_device, ["left", "right"])
    assert [p.kind for p in both] == ["pixels", "pixels"]
    for name, pixels in zip(["left", "right"], both):
        uv, status = pixels.read()
        cpu, cpu_status = rig.project(points, camera=name)
        assert (status == cpu_status).all()
        inside = (cpu_status == 0) & (cpu[:, 0] > 0) & (cpu[:, 0] < 1280) & (cpu[:, 1] > 0) & (cpu[:, 1] < 1024)
        assert inside.sum() > 2000 and np.abs(uv[inside] - cpu[inside]).max() < 1e-3


def test_device_arrays_refuse_what_does_not_fit(rig):
    pixels = flatport.gpu.upload(rig, [[1.0, 2.0]], "pixels")
    rays = flatport.gpu.upload(rig, [[0.0, 0.0, 0.0, 0.0, 0.0, 1.0]] * 2, "rays")
    with pytest.raises(ValueError, match="1 rows a, 2 rows b"):
        flatport.gpu.triangulate(rig.backproject(pixels), rays)
    with pytest.raises(ValueError, match="takes pixels, got rays"):
        flatport.gpu.backproject(rig, rays)
    with pytest.raises(TypeError, match="DeviceArray"):
        flatport.gpu.triangulate(np.zeros((1, 6)), rays)
    other = flatport.load_rig(EXAMPLE)
    elsewhere = flatport.gpu.upload(other, [[1.0, 2.0]], "pixels")
    with pytest.raises(ValueError, match="another device"):
        flatport.gpu.triangulate(rig.backproject(pixels), flatport.gpu.backproject(other, elsewhere))
