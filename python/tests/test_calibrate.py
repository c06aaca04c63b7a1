"""simulate → calibrate → sweep through Python, and a calibrated rig exported for
colmap_underwater."""

import json

import numpy as np
import pytest

import flatport
from test_export import flatport_img_from_cam, read_cameras_txt, rotation_from_qvec
from test_geometry import EXAMPLE, points_in_view


@pytest.fixture(scope="module")
def scene():
    truth_rig = flatport.load_rig(EXAMPLE)
    simulation = flatport.simulate(truth_rig, board=(9, 6, 0.04), views=12, noise=0.1, seed=5)
    d = truth_rig.to_dict()
    d["interface"]["normal"], d["interface"]["distance"] = [0.0, 0.0, 1.0], 0.01
    return truth_rig, flatport.Rig.from_dict(d), simulation


def test_simulate_is_seeded(scene):
    truth_rig, _, simulation = scene
    again = flatport.simulate(truth_rig, board=(9, 6, 0.04), views=12, noise=0.1, seed=5)
    assert again.observations == simulation.observations
    assert simulation.observations["board"] == {"rows": 6, "cols": 9, "square": 0.04}
    assert len(simulation.observations["views"]) == 12
    assert simulation.truth["seed"] == 5


def test_calibrate_finds_the_true_port_with_its_sigma(scene):
    truth_rig, start, simulation = scene
    result = flatport.calibrate(start, simulation.observations, method="auto")
    assert result.report["fits"] and result.rig is not None
    n, n_true = np.array(result.rig.interface["normal"]), np.array(truth_rig.interface["normal"])
    axis_error_deg = np.degrees(np.arccos(min(1.0, n @ n_true)))
    # σ from the covariance: the errors stay within a few σ of 0.1 px noise.
    assert result.sigma["tilt_deg"] > 0 and result.sigma["air_distance"] > 0
    assert axis_error_deg < 5 * max(result.sigma["tilt_deg"], result.sigma["azimuth_deg"] * np.sin(np.radians(8)))
    assert abs(result.rig.interface["distance"] - 0.02) < 5 * result.sigma["air_distance"]
    assert 0.05 < result.sigma["sigma_px"] < 0.2
    # The cameras are the start rig's; only the interface changed.
    assert result.rig.cameras == start.cameras


def test_calibrate_writes_the_report_page(scene, tmp_path):
    # Issue 47: report_dir writes what `calibrate --report-dir` writes.
    _, start, simulation = scene
    report_dir = tmp_path / "report"
    result = flatport.calibrate(start, simulation.observations, report_dir=report_dir)
    assert result.report["fits"]
    page = (report_dir / "index.html").read_text()
    assert "What footage to add" in page and "The worst-determined parameter" in page
    for name in ("rig_top.png", "rig_side.png", "quiver_0_left.png", "histogram.png"):
        assert (report_dir / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name
    numbers = json.loads((report_dir / "report.json").read_text())
    assert numbers["advice"]["worst"] and numbers["advice"]["view"]["distance_m"] > 0


def test_calibrate_takes_a_path_and_json_text(scene, tmp_path):
    _, start, simulation = scene
    path = tmp_path / "observations.json"
    path.write_text(json.dumps(simulation.observations))
    by_path = flatport.calibrate(start, path, method="consecutive")
    by_text = flatport.calibrate(start, json.dumps(simulation.observations), method="consecutive", estimate="axis,distance")
    assert by_path.rig.interface == by_text.rig.interface
    assert by_path.sigma["tilt_deg"] is None  # the consecutive method has no covariance


def test_calibrate_any_rig_one_camera_and_extrinsics(scene):
    truth_rig, start, simulation = scene
    # One camera in its housing: the left camera alone, its images keyed by its name.
    d = start.to_dict()
    d["cameras"] = d["cameras"][:1]
    one = flatport.Rig.from_dict(d)
    name = one.camera_names[0]
    views = [{name: v["left"]} for v in simulation.observations["views"]]
    result = flatport.calibrate(one, {"board": simulation.observations["board"], "views": views})
    assert result.report["fits"] and result.rig is not None
    assert [p["name"] for p in result.report["ports"]] == ["shared"]
    n, n_true = np.array(result.rig.interface["normal"]), np.array(truth_rig.interface["normal"])
    axis_error_deg = np.degrees(np.arccos(min(1.0, n @ n_true)))
    assert result.sigma["tilt_deg"] > 0 and result.sigma["air_distance"] > 0
    assert axis_error_deg < 0.2  # issue 10's bound for one camera, 10 views at 0.125 px
    assert abs(result.rig.interface["distance"] - truth_rig.interface["distance"]) < 3.2e-3
    # The stereo pair with its extrinsics estimated too: a σ for the second camera's R and t.
    both = flatport.calibrate(start, simulation.observations, estimate=["axis", "distance", "extrinsics"])
    assert both.report["fits"] and both.report["estimate"] == "axis,distance,extrinsics"
    assert both.report["cameras"][1]["rotation_std_deg"] is not None
    assert both.report["cameras"][0]["rotation_std_deg"] is None  # the master defines the frame


def test_calibrate_names_bad_arguments(scene):
    _, start, simulation = scene
    with pytest.raises(ValueError, match="'magic' is not something to estimate"):
        flatport.calibrate(start, simulation.observations, estimate="axis,magic")
    with pytest.raises(ValueError, match="layer:9"):
        flatport.calibrate(start, simulation.observations, estimate="axis,layer:9")
    with pytest.raises(ValueError, match="method"):
        flatport.calibrate(start, simulation.observations, method="magic")
    with pytest.raises(ValueError, match="sqare"):
        bad = dict(simulation.observations, board={"rows": 6, "cols": 9, "sqare": 0.04})
        flatport.calibrate(start, bad)


def test_sweep_arrays(scene):
    truth_rig, start, simulation = scene
    result = flatport.sweep(start, simulation.observations, cost="affine-grid", tilt_deg=(0, 16, 9), azimuth_deg=(-180, 180, 13))
    assert result.cost.shape == (9, 13) and result.distance.shape == (9, 13)
    assert result.tilt_deg.shape == (9,) and result.azimuth_deg[-1] == 180
    minimum = result.summary["minimum"]
    assert result.cost.flat[minimum["cell"]] == minimum["cost"] == np.nanmin(result.cost)
    # The well lies near the true axis: tilt 8.05°, azimuth 45°.
    assert abs(minimum["tilt_deg"] - 8) <= 2 and abs(minimum["azimuth_deg"] - 45) <= 30
    with_distance = flatport.sweep(start, simulation.observations, cost="reprojection", tilt_deg=(7, 9, 3), azimuth_deg=(40, 50, 3), distance=(0.015, 0.025, 3))
    assert with_distance.cost.shape == (3, 3, 3)
    assert np.allclose(with_distance.distance[0, 0], [0.015, 0.02, 0.025])


def test_a_calibrated_rig_exported_for_colmap_projects_as_flatport(scene):
    _, start, simulation = scene
    rig = flatport.calibrate(start, simulation.observations, method="simultaneous").rig
    files = rig.export_colmap()
    cameras = read_cameras_txt(files["cameras.txt"])
    poses = {c["camera_id"]: c for c in json.loads(files["rig_config.json"])[0]["cameras"]}
    points = points_in_view(25, seed=31)
    for k in range(2):
        R, t = rotation_from_qvec(poses[k + 1]["rel_qvec"]), np.array(poses[k + 1]["rel_tvec"])
        uv, status = rig.project(points, camera=k)
        assert (status == 0).all()
        for point, expected in zip(points, uv):
            assert np.abs(flatport_img_from_cam(cameras[k + 1], R @ point + t) - (expected + 0.5)).max() < 1e-6
