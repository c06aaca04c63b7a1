"""flatport.calibrate_targetless on scenes rendered by the CLI (`flatport render --scene`) with a
true rig: the port reset to the naive guess (axis on the master's z, 10 mm of air) and calibrated
from the images alone. The oracle is the rig the images were rendered with (independent of the
calibration); the CLI's `calibrate --targetless` on the same folder gives the same rig; a scene
that cannot pin the air layer raises CalibrationRefused naming it; bad input raises ValueError."""

import json
import shutil
import subprocess

import numpy as np
import pytest

import flatport
from test_geometry import flatport_binary
from test_stereo import read_grey_png

pytestmark = pytest.mark.skipif(flatport_binary() is None, reason="no flatport binary (set FLATPORT_BIN or build target/release/flatport)")

# A pair behind one shared port tilted 8° with 14 mm of glass and 50 mm of air, a 0.2 m baseline
# converging by 4°, lens distortion, 320 x 256 (tests/stereo_common's SHARED_PORT_PAIR).
TRUE_RIG = {
    "cameras": [
        {"name": "left", "width": 320, "height": 256, "fx": 260, "fy": 260, "cx": 159.5, "cy": 127.5,
         "distortion": [-0.08, 0.012, 0.0004, -0.0003, 0.0]},
        {"name": "right", "width": 320, "height": 256, "fx": 260, "fy": 260, "cx": 159.5, "cy": 127.5,
         "distortion": [-0.08, 0.012, 0.0, 0.0, 0.0],
         "rotation": [[0.9975640502598242, 0.0, 0.0697564737441253], [0.0, 1.0, 0.0],
                      [-0.0697564737441253, 0.0, 0.9975640502598242]],
         "translation": [-0.19951281005196484, 0.0, 0.013951294748825061]},
    ],
    "interface": {"normal": [0.1, 0.1, 1.0], "distance": 0.05,
                  "layers": [{"thickness": 0.014, "index": 1.473}], "index_air": 1.003, "index_water": 1.333},
}

SEABED_AND_ROCK = [
    {"height_field": {"origin": [0, 0, 1.6], "normal": [0, 0, -1],
                      "relief": {"amplitude": 0.05, "wavelength": 0.7, "waves": 6, "seed": 3},
                      "texture": {"noise": {"scale": 0.15, "octaves": 4, "contrast": 3.0, "seed": 103}}}},
    {"sphere": {"centre": [0.12, 0.05, 1.3], "radius": 0.15,
                "texture": {"noise": {"scale": 0.06, "octaves": 4, "contrast": 3.0, "seed": 12}}}},
]

FAR_PLANE = [
    {"plane": {"point": [0, 0, 8], "normal": [0, 0, -1],
               "texture": {"noise": {"scale": 0.6, "octaves": 4, "contrast": 3.0, "seed": 31}}}},
]


def render(folder, surfaces):
    """Renders `surfaces` with the true rig into `folder`/shots; returns the shots folder."""
    scene = folder / "scene.json"
    scene.write_text(json.dumps({"rig": TRUE_RIG, "background": 0.35, "surfaces": surfaces}))
    shots = folder / "shots"
    subprocess.run(
        [flatport_binary(), "render", "--scene", str(scene), "--device", "cpu", "--supersample", "3", "--quiet",
         "-o", str(shots)],
        check=True, capture_output=True,
    )
    return shots


def naive_rig():
    """The true cameras with the port reset to the naive guess."""
    naive = json.loads(json.dumps(TRUE_RIG))
    naive["interface"]["normal"] = [0.0, 0.0, 1.0]
    naive["interface"]["distance"] = 0.01
    return flatport.Rig.from_dict(naive)


def port_errors(rig):
    """(axis error in degrees, air distance error in metres) of `rig`'s shared port vs the truth."""
    fitted = rig.interface
    n = np.asarray(fitted["normal"], dtype=np.float64)
    truth = np.asarray(TRUE_RIG["interface"]["normal"], dtype=np.float64)
    cosine = n @ truth / np.linalg.norm(n) / np.linalg.norm(truth)
    return np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))), fitted["distance"] - TRUE_RIG["interface"]["distance"]


@pytest.fixture(scope="module")
def seabed(tmp_path_factory):
    """The seabed-and-rock shots, the naive rig file and the Python result on the folder."""
    root = tmp_path_factory.mktemp("targetless")
    shots = render(root, SEABED_AND_ROCK)
    naive = root / "naive.json"
    naive.write_text(naive_rig().to_json())
    result = flatport.calibrate_targetless(naive, shots, output=root / "python_rig.json")
    return root, shots, naive, result


def test_recovers_the_rendered_port(seabed):
    """Against the renderer's truth: axis within 0.1°, air layer within 1.5 mm, each within a few σ."""
    root, _, naive, result = seabed
    axis, air = port_errors(result.rig)
    port = result.ports[0]
    print(f"axis off by {axis:.4f}° (σ {port['axis_std_deg']:.4f}°), air off by {air * 1e3:+.3f} mm "
          f"(σ {port['distance']['std'] * 1e3:.3f} mm), {result.tracks} tracks, {result.rms_px:.4f} px RMS")
    assert axis < 0.1, axis
    assert abs(air) < 1.5e-3, air
    assert port["name"] == "shared" and port["normal"].shape == (3,)
    assert 0 < port["axis_std_deg"] < 0.1 and 0 < port["distance"]["std"] < 2e-3
    assert port["thicknesses"] == [{"value": 0.014, "std": None}]  # known, not estimated
    assert result.report["pinned"] and result.report["unpinned"] == []
    assert result.tracks == result.report["tracks"] > 500 and result.rms_px < 0.1
    assert result.report["candidates"] >= result.tracks
    # The cameras are the input's (as read from the file: rotations pass through quaternions);
    # the file written is the rig returned.
    assert result.rig.cameras == flatport.load_rig(naive).cameras
    assert json.loads((root / "python_rig.json").read_text()) == result.rig.to_dict()


def test_equal_to_the_cli_and_to_arrays(seabed):
    """The CLI on the same folder writes the same rig, to the last bit; the same frames given as
    arrays give the same fit."""
    root, shots, naive, result = seabed
    subprocess.run(
        [flatport_binary(), "calibrate", "--images", str(shots), "--rig", str(naive), "--targetless", "-q",
         "-o", str(root / "cli_rig.json")],
        check=True, capture_output=True,
    )
    assert json.loads((root / "cli_rig.json").read_text()) == result.rig.to_dict()
    images = [read_grey_png(shots / camera / "frame_000.png") for camera in ("left", "right")]
    from_arrays = flatport.calibrate_targetless(naive, images)
    assert from_arrays.rig.to_dict() == result.rig.to_dict()
    assert from_arrays.report["tracks"] == result.report["tracks"]


def test_a_scene_that_cannot_pin_the_air_layer_is_refused(tmp_path):
    """A textured plane 8 m away seen head-on: every point at one depth, the air layer's σ ≈ 10 mm.
    The refusal names the parameter and its σ, its report holds the fit, no rig is written."""
    shots = render(tmp_path, FAR_PLANE)
    output = tmp_path / "rig.json"
    with pytest.raises(flatport.CalibrationRefused, match=r"shared distance: σ [0-9.]+ mm > 2 mm") as refused:
        flatport.calibrate_targetless(naive_rig(), shots, output=output)
    report = refused.value.report
    assert not report["pinned"]
    assert [u["parameter"] for u in report["unpinned"]] == ["shared distance"]
    assert report["unpinned"][0]["sigma"] > 2e-3 and report["ports"][0]["distance"]["std"] > 2e-3
    assert "not written" in str(refused.value)
    assert isinstance(refused.value, ValueError) and not output.exists()


def test_bad_input_is_refused(seabed, tmp_path):
    _, shots, naive, _ = seabed
    one_camera = tmp_path / "one"
    shutil.copytree(shots / "left", one_camera / "left")
    with pytest.raises(ValueError, match="no folder for camera 'right'"):
        flatport.calibrate_targetless(naive, one_camera)
    with pytest.raises(ValueError, match="intrinsics"):
        flatport.calibrate_targetless(naive, shots, estimate="axis,intrinsics")
    with pytest.raises(ValueError, match="--frames 5"):
        flatport.calibrate_targetless(naive, shots, frames="5:")
    with pytest.raises(ValueError, match="images for a rig of 2 cameras"):
        flatport.calibrate_targetless(naive, [np.zeros((256, 320), dtype=np.float32)])
