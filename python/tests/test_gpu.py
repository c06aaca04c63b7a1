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
