"""flatport.calibrate_images on a calibration set rendered by the CLI (`flatport render
--calibration-set`): the same rig, numbers and report as `flatport calibrate --images` on the same
set, the renderer's true rig recovered within the fit's σ, and bad input refused with the
library's message naming the folder."""

import json
import shutil
import subprocess

import numpy as np
import pytest

import flatport
from test_geometry import EXAMPLE, ROOT, flatport_binary

BOARD = ROOT / "data" / "boards" / "charuco_7x5.json"
# The example rig's glass and the index of the air in its housing (data/example_rig.json).
GLASS = (0.014, 1.473)
INDEX_AIR = 1.003

pytestmark = pytest.mark.skipif(flatport_binary() is None, reason="no flatport binary (set FLATPORT_BIN or build target/release/flatport)")


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """A small set (12 synchronized underwater views, 8 in-air views per camera) and the result
    of the Python call on it, computed once."""
    root = tmp_path_factory.mktemp("calibration_set")
    subprocess.run(
        [flatport_binary(), "render", "--rig", str(EXAMPLE), "--board", str(BOARD), "--calibration-set",
         "--views", "12", "--air-views", "8", "-o", str(root / "set")],
        check=True, capture_output=True,
    )
    result = flatport.calibrate_images(
        root / "set", BOARD, "shared", glass=GLASS, index_air=INDEX_AIR,
        output=root / "python_rig.json", report=root / "python_report.json", report_dir=root / "python_page",
    )
    return root, result


def test_equal_to_the_cli(rendered):
    root, result = rendered
    subprocess.run(
        [flatport_binary(), "calibrate", "--images", str(root / "set"), "--board", str(BOARD), "--port", "shared",
         "--glass", f"{GLASS[0]}:{GLASS[1]}", "--index-air", str(INDEX_AIR), "--device", "cpu", "-q",
         "-o", str(root / "cli_rig.json"), "--report", str(root / "cli_report.json"),
         "--report-dir", str(root / "cli_page")],
        check=True, capture_output=True,
    )
    cli_rig = (root / "cli_rig.json").read_text()
    # The same numbers, to the last bit: the rig returned and the file written.
    assert result.rig.to_dict() == json.loads(cli_rig)
    assert (root / "python_rig.json").read_text() == cli_rig
    cli_report = json.loads((root / "cli_report.json").read_text())
    python_report = json.loads((root / "python_report.json").read_text())
    assert python_report == result.report
    timing = {"seconds", "stages"}  # wall-clock times differ between runs
    assert {k: v for k, v in result.report.items() if k not in timing} == {k: v for k, v in cli_report.items() if k not in timing}
    # The result's fields are the report's, arrays as numpy.
    assert result.validation == cli_report["held_out"] and result.validation["frames"]
    assert result.dropped_frames == cli_report["dropped_frames"]
    assert result.dropped_corners == cli_report["dropped_corners"]
    assert [p["name"] for p in result.ports] == ["shared"]
    np.testing.assert_array_equal(result.ports[0]["normal"], cli_report["ports"][0]["normal"])
    left = result.intrinsics["left"]
    assert isinstance(left["distortion"], np.ndarray) and left["distortion"].shape == (5,)
    assert left["view_rms_px"].shape == (8,)
    assert left["fx"] == cli_report["intrinsics"][0]["fx"]
    # The report page (issue 47): the same numbers and advice, only the command line differs.
    page = {k: v for k, v in json.loads((root / "python_page" / "report.json").read_text()).items() if k != "command"}
    assert page == {k: v for k, v in json.loads((root / "cli_page" / "report.json").read_text()).items() if k != "command"}
    assert page["advice"]["view"] and (root / "python_page" / "index.html").is_file()


def test_recovers_the_rendered_rig(rendered):
    """Against the renderer's truth (an independent oracle): the rig it rendered the set with."""
    _, result = rendered
    truth = flatport.load_rig(EXAMPLE)
    assert result.rig.camera_names == ["left", "right"]
    for camera in truth.cameras:
        fit = result.intrinsics[camera["name"]]
        for key in ("fx", "fy", "cx", "cy"):
            assert abs(fit[key] - camera[key]) < 4 * fit["std"][key], (camera["name"], key, fit[key], fit["std"][key])
        np.testing.assert_allclose(fit["distortion"][:2], camera["distortion"][:2], atol=1e-3)
    port = result.ports[0]
    n, n_true = port["normal"], np.asarray(truth.interface["normal"]) / np.linalg.norm(truth.interface["normal"])
    axis_error_deg = np.degrees(np.arccos(min(1.0, float(n @ n_true))))
    assert axis_error_deg < 0.05, axis_error_deg
    distance = port["distance"]
    assert abs(distance["value"] - truth.interface["distance"]) < 4 * distance["std"], distance
    assert port["thicknesses"] == [{"value": GLASS[0], "std": None}]
    # The held-out frames (20 % of 12, floored) reproject and triangulate as the fitted ones do.
    assert len(result.validation["frames"]) == 2
    assert result.validation["rms_px"] < 0.05
    assert result.validation["median_distance_error_percent_of_square"] < 0.2
    np.testing.assert_allclose(result.rig.cameras[1]["translation"], truth.cameras[1]["translation"], atol=1e-4)


def test_the_cameras_of_a_rig_instead_of_air(rendered, tmp_path):
    root, _ = rendered
    # Only water/: the lenses come from the rig (a Rig or a path), air/ is not read.
    shutil.copytree(root / "set" / "water", tmp_path / "set" / "water")
    truth = flatport.load_rig(EXAMPLE)
    by_rig = flatport.calibrate_images(tmp_path / "set", BOARD, "shared", glass=GLASS, index_air=INDEX_AIR, rig=truth)
    by_path = flatport.calibrate_images(tmp_path / "set", BOARD, "shared", glass=GLASS, index_air=INDEX_AIR, rig=EXAMPLE)
    assert by_rig.intrinsics == {} and by_rig.report["intrinsics"] == []
    assert by_rig.rig.to_dict() == by_path.rig.to_dict()
    lens = ("width", "height", "fx", "fy", "cx", "cy", "distortion")
    for got, want in zip(by_rig.rig.cameras, truth.cameras):
        assert {k: got[k] for k in lens} == {k: want[k] for k in lens}
    # Without air/ and without a rig, every lens comes from the underwater frames.
    alone = flatport.calibrate_images(tmp_path / "set", BOARD, "shared", glass=GLASS, index_air=INDEX_AIR)
    assert alone.intrinsics == {} and alone.report["verdict"]["grade"] in ("good", "usable")
    for got, want in zip(alone.rig.cameras, truth.cameras):
        assert abs(got["fx"] - want["fx"]) < 0.005 * want["fx"], (got, want)
        assert abs(got["cx"] - want["cx"]) < 3.0 and abs(got["cy"] - want["cy"]) < 3.0, (got, want)


def test_bad_input_is_refused_with_the_folder_named(rendered, tmp_path):
    root, _ = rendered
    shutil.copytree(root / "set" / "air", tmp_path / "set" / "air")
    with pytest.raises(ValueError, match=r"no water/ folder") as error:
        flatport.calibrate_images(tmp_path / "set", BOARD, "shared", glass=GLASS)
    assert str(tmp_path / "set") in str(error.value)
    with pytest.raises(ValueError, match="port must be"):
        flatport.calibrate_images(root / "set", BOARD, "tank")
    with pytest.raises(ValueError, match="bare water surface"):
        flatport.calibrate_images(root / "set", BOARD, "surface", glass=GLASS)
    with pytest.raises(ValueError, match="one port is in front of every camera"):
        flatport.calibrate_images(root / "set", BOARD, "shared", glass={"left": GLASS})
    with pytest.raises(ValueError, match="thickness between 0 and 1 m"):
        flatport.calibrate_images(root / "set", BOARD, "shared", glass=(14.0, 1.473))
    with pytest.raises(ValueError, match="pair"):
        flatport.calibrate_images(root / "set", BOARD, "shared", glass=0.014)
    with pytest.raises(ValueError, match="no-such-board.json"):
        flatport.calibrate_images(root / "set", tmp_path / "no-such-board.json", "shared")
    with pytest.raises(ValueError, match="max_frames"):
        flatport.calibrate_images(root / "set", BOARD, "shared", max_frames=2)
    with pytest.raises(ValueError, match="holdout"):
        flatport.calibrate_images(root / "set", BOARD, "shared", holdout=1.5)
    with pytest.raises(ValueError, match="refine_intrinsics must be"):
        flatport.calibrate_images(root / "set", BOARD, "shared", refine_intrinsics="sometimes")


def test_a_rig_that_does_not_fit_is_refused(rendered, tmp_path):
    root, _ = rendered
    # A bound below the corner noise: the fit is refused as the CLI refuses it, the report written,
    # the rig not.
    with pytest.raises(flatport.CalibrationRefused, match="does not fit") as error:
        flatport.calibrate_images(
            root / "set", BOARD, "shared", glass=GLASS, max_rms_px=1e-4,
            output=tmp_path / "rig.json", report=tmp_path / "report.json",
        )
    assert isinstance(error.value, ValueError)
    assert error.value.report["fits"] is False
    assert json.loads((tmp_path / "report.json").read_text()) == error.value.report
    assert not (tmp_path / "rig.json").exists()
    assert str(tmp_path / "rig.json") in str(error.value)
