"""Exports read back by independent code: colmap_underwater's FLATPORT camera model re-implemented
here in numpy from its source (src/colmap/sensor/models_refrac.h: FlatPort::CamFromImg;
src/colmap/sensor/ray3d.h: RayPlaneIntersection, ComputeRefraction; src/colmap/sensor/models.h:
OPENCV / FULL_OPENCV), reading the exported cameras.txt and rig_config.json the way its readers do;
OpenCV YAML read back by OpenCV's own cv::FileStorage (opencv-python-headless) and by the crate's
importer; ray maps against back-projection."""

import json
import os
import pathlib
import subprocess

import numpy as np
import pytest

import flatport
from test_geometry import EXAMPLE, flatport_binary, points_in_view

ROOT = pathlib.Path(__file__).resolve().parents[2]

# colmap_underwater's models and how many lens parameters each takes (COLMAP's models.h).
LENS_PARAMS = {"OPENCV": 8, "FULL_OPENCV": 12}


def read_cameras_txt(text):
    """Reconstruction::ReadCamerasText of colmap_underwater: id, model, width, height, the model's
    parameters, then (when the line goes on) the refractive model's name and its parameters; items
    split at single spaces. The COLMAP 3.12 based port's reader skips a REFRAC token first."""
    cameras = {}
    for line in text.splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        items = line.split(" ")
        camera_id, model, width, height = int(items[0]), items[1], int(items[2]), int(items[3])
        count = LENS_PARAMS[model]
        lens = [float(v) for v in items[4 : 4 + count]]
        rest = items[4 + count :]
        if rest[0] == "REFRAC":
            rest = rest[1:]
        assert rest[0] == "FLATPORT" and len(rest) == 9, line
        cameras[camera_id] = dict(model=model, width=width, height=height, lens=np.array(lens), port=np.array([float(v) for v in rest[1:]]))
    return cameras


def lens_distort(model, lens, x, y):
    fx, fy, cx, cy, k1, k2, p1, p2 = lens[:8]
    k3, k4, k5, k6 = lens[8:12] if model == "FULL_OPENCV" else (0.0, 0.0, 0.0, 0.0)
    r2 = x * x + y * y
    radial = (1 + k1 * r2 + k2 * r2**2 + k3 * r2**3) / (1 + k4 * r2 + k5 * r2**2 + k6 * r2**3)
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + 2 * p2 * x * y + p1 * (r2 + 2 * y * y)
    return fx * xd + cx, fy * yd + cy


def lens_cam_from_img(model, lens, u, v):
    """Normalised coordinates of pixel (u, v): Newton on the distortion, numeric Jacobian."""
    fx, fy, cx, cy = lens[:4]
    x, y = (u - cx) / fx, (v - cy) / fy
    h = 1e-8
    for _ in range(40):
        pu, pv = lens_distort(model, lens, x, y)
        au, av = lens_distort(model, lens, x + h, y)
        bu, bv = lens_distort(model, lens, x, y + h)
        j = np.array([[(au - pu) / h, (bu - pu) / h], [(av - pv) / h, (bv - pv) / h]])
        step = np.linalg.solve(j, np.array([pu - u, pv - v]))
        x, y = x - step[0], y - step[1]
    return x, y


def refraction(normal, n1, n2, v):
    """ComputeRefraction of ray3d.h."""
    if n1 == n2:
        return v
    r = n1 / n2
    c = normal @ v
    v = r * v - (r * c - np.sqrt(1 - r * r * (1 - c * c))) * normal
    return v / np.linalg.norm(v)


def flatport_cam_from_img(camera, u, v):
    """FlatPort::CamFromImg: the water ray (origin, direction) of pixel (u, v), camera frame."""
    x, y = lens_cam_from_img(camera["model"], camera["lens"], u, v)
    direction = np.array([x, y, 1.0])
    direction /= np.linalg.norm(direction)
    nx, ny, nz, int_dist, int_thick, na, ng, nw = camera["port"]
    normal = np.array([nx, ny, nz])
    origin = np.zeros(3)
    for distance, (n1, n2) in ((int_dist, (na, ng)), (int_dist + int_thick, (ng, nw))):
        # RayPlaneIntersection: the plane through distance · normal with that normal.
        origin = origin + ((distance * normal - origin) @ normal / (direction @ normal)) * direction
        direction = refraction(normal, n1, n2, direction)
    return origin, direction


def flatport_img_from_cam(camera, point):
    """The pixel whose FlatPort ray passes through ``point`` (camera frame): Gauss–Newton on the
    ray's miss of the point, numeric Jacobian, from the pinhole projection (as COLMAP's
    IterativeProjection does, with its own residual)."""
    fx, fy, cx, cy = camera["lens"][:4]
    p = np.array([fx * point[0] / point[2] + cx, fy * point[1] / point[2] + cy])

    def miss(q):
        o, d = flatport_cam_from_img(camera, q[0], q[1])
        rel = point - o
        return rel - (rel @ d) * d

    for _ in range(30):
        r = miss(p)
        h = 1e-6
        j = np.stack([(miss(p + [h, 0]) - r) / h, (miss(p + [0, h]) - r) / h], axis=1)
        step = np.linalg.lstsq(j, r, rcond=None)[0]
        p = p - step
        if np.abs(step).max() < 1e-12:
            break
    return p


def rotation_from_qvec(q):
    w, x, y, z = q
    return np.array([
        [1 - 2 * y * y - 2 * z * z, 2 * x * y - 2 * w * z, 2 * x * z + 2 * w * y],
        [2 * x * y + 2 * w * z, 1 - 2 * x * x - 2 * z * z, 2 * y * z - 2 * w * x],
        [2 * x * z - 2 * w * y, 2 * y * z + 2 * w * x, 1 - 2 * x * x - 2 * y * y],
    ])


def full_opencv_rig():
    """The example rig with a k3 term on the right camera (FULL_OPENCV) and a tilted port."""
    d = json.loads(EXAMPLE.read_text())
    d["cameras"][1]["distortion"] = [-0.08, 0.012, 0.0003, -0.0002, 0.004]
    d["cameras"][0]["cx"], d["cameras"][0]["cy"] = 641.3, 509.8
    return flatport.Rig.from_dict(d)


@pytest.mark.parametrize("make_rig", [lambda: flatport.load_rig(EXAMPLE), full_opencv_rig], ids=["opencv", "full_opencv"])
def test_colmap_flatport_model_projects_held_out_points_as_flatport_plus_half_a_pixel(make_rig):
    rig = make_rig()
    files = rig.export_colmap()
    cameras = read_cameras_txt(files["cameras.txt"])
    config = json.loads(files["rig_config.json"])
    assert config[0]["ref_camera_id"] == 1
    poses = {c["camera_id"]: c for c in config[0]["cameras"]}
    points = points_in_view(40, seed=21)
    for k, name in enumerate(rig.camera_names):
        camera = cameras[k + 1]
        assert camera["model"] == ("FULL_OPENCV" if rig.cameras[k].get("distortion", [0] * 5)[4] != 0 else "OPENCV")
        R, t = rotation_from_qvec(poses[k + 1]["rel_qvec"]), np.array(poses[k + 1]["rel_tvec"])
        expected, status = rig.project(points, camera=name)
        assert (status == 0).all()
        for point, uv in zip(points, expected):
            pixel = flatport_img_from_cam(camera, R @ point + t)
            # COLMAP's pixel centres are flatport's + 0.5; 1e-6 px is the bound.
            assert np.abs(pixel - (uv + 0.5)).max() < 1e-6, (name, point, pixel, uv)


def test_colmap_rays_are_flatport_rays_in_the_camera_frame():
    rig = full_opencv_rig()
    cameras = read_cameras_txt(rig.export_colmap()["cameras.txt"])
    rng = np.random.default_rng(22)
    pixels = np.stack([rng.uniform(50, 1230, 50), rng.uniform(50, 970, 50)], axis=1)
    for k in range(2):
        rays, status = rig.backproject(pixels, camera=k)
        R, t = np.array(rig.cameras[k].get("rotation", np.eye(3))), np.array(rig.cameras[k].get("translation", [0, 0, 0]))
        for pixel, ray in zip(pixels, rays):
            origin, direction = flatport_cam_from_img(cameras[k + 1], pixel[0] + 0.5, pixel[1] + 0.5)
            # The same water ray: flatport's origin (master frame, on the outer interface) is on it.
            assert np.abs(R @ ray[3:] - direction).max() < 1e-9
            rel = R @ ray[:3] + t - origin
            assert np.linalg.norm(rel - (rel @ direction) * direction) < 1e-9


def test_rigs_txt_and_the_refrac_token_dialect():
    rig = full_opencv_rig()
    files = rig.export_colmap()
    line = [l for l in files["rigs.txt"].splitlines() if not l.startswith("#")][0].split(" ")
    # RIG_ID NUM_SENSORS REF_SENSOR_TYPE REF_SENSOR_ID, then CAMERA 2 HAS_POSE QW QX QY QZ TX TY TZ.
    assert line[:7] == ["1", "2", "CAMERA", "1", "CAMERA", "2", "1"]
    R, t = rotation_from_qvec([float(v) for v in line[7:11]]), np.array([float(v) for v in line[11:14]])
    assert np.abs(R - np.array(rig.cameras[1]["rotation"])).max() < 1e-15
    assert np.abs(t - np.array(rig.cameras[1]["translation"])).max() < 1e-15
    token = rig.export_colmap(refrac_token=True)["cameras.txt"]
    assert token == files["cameras.txt"].replace(" FLATPORT ", " REFRAC FLATPORT ")
    assert read_cameras_txt(token).keys() == read_cameras_txt(files["cameras.txt"]).keys()


def test_colmap_refuses_two_layers():
    d = json.loads(EXAMPLE.read_text())
    d["interface"]["layers"].append({"thickness": 0.005, "index": 1.5})
    with pytest.raises(ValueError, match="one glass layer"):
        flatport.Rig.from_dict(d).export_colmap()


def test_raymap_equals_backproject_on_every_pixel():
    rig = flatport.load_rig(EXAMPLE)
    rays, status = rig.raymap(camera="right")
    assert rays.shape == (1024, 1280, 6) and status.shape == (1024, 1280)
    v, u = np.mgrid[0:1024, 0:1280]
    pixels = np.stack([u.ravel(), v.ravel()], axis=1).astype(np.float64)
    expected, expected_status = rig.backproject(pixels, camera="right")
    np.testing.assert_array_equal(status.ravel(), expected_status)
    ok = expected_status == 0
    assert ok.mean() > 0.99
    assert np.abs(rays.reshape(-1, 6)[ok] - expected[ok]).max() <= 1e-12
    assert np.isnan(rays.reshape(-1, 6)[~ok]).all()


@pytest.mark.skipif(flatport_binary() is None, reason="no flatport binary")
def test_cli_exports(tmp_path):
    rig = flatport.load_rig(EXAMPLE)
    binary = flatport_binary()
    subprocess.run([binary, "export", "colmap", "--rig", str(EXAMPLE), "--output", str(tmp_path / "colmap")], check=True, capture_output=True)
    for name, text in rig.export_colmap().items():
        assert (tmp_path / "colmap" / name).read_text() == text, name
    subprocess.run([binary, "export", "colmap", "--rig", str(EXAMPLE), "--refrac-token", "--output", str(tmp_path / "colmap312")], check=True, capture_output=True)
    assert (tmp_path / "colmap312" / "cameras.txt").read_text() == rig.export_colmap(refrac_token=True)["cameras.txt"]
    subprocess.run([binary, "export", "opencv", "--rig", str(EXAMPLE), "--output", str(tmp_path / "stereo.yml")], check=True, capture_output=True)
    assert (tmp_path / "stereo.yml").read_text() == rig.export_opencv()
    # The YAML goes back into a rig with the same cameras.
    back = tmp_path / "back.json"
    subprocess.run([binary, "rig", "from-opencv", str(tmp_path / "stereo.yml"), "--normal", "0.1,0.1,1", "--distance", "0.02", "--layer", "0.014:1.473",
                    "--index-air", "1.003", "--index-water", "1.333", "--output", str(back)], check=True, capture_output=True)
    again = flatport.load_rig(back)
    for a, b in zip(again.cameras, rig.cameras):
        for key in ("fx", "fy", "cx", "cy", "distortion", "translation", "width", "height"):
            assert np.allclose(a.get(key, 0), b.get(key, 0), rtol=0, atol=1e-15), key
    raymap = tmp_path / "rays.npy"
    subprocess.run([binary, "export", "raymap", "--rig", str(EXAMPLE), "--camera", "left", "--device", "cpu", "--output", str(raymap)], check=True, capture_output=True)
    rays = np.load(raymap)
    assert rays.shape == (1024, 1280, 6) and rays.dtype == np.float64
    np.testing.assert_array_equal(rays, rig.raymap(camera="left")[0])
    raymap32 = tmp_path / "rays32.npy"
    subprocess.run([binary, "export", "raymap", "--rig", str(EXAMPLE), "--device", "cpu", "--precision", "f32", "--output", str(raymap32)], check=True, capture_output=True)
    rays32 = np.load(raymap32)
    assert rays32.dtype == np.float32
    np.testing.assert_array_equal(rays32, rays.astype(np.float32))


def test_opencv_filestorage_reads_the_export(tmp_path):
    """OpenCV itself (opencv-python-headless, which scripts/test.sh installs) reads the exported
    YAML with cv::FileStorage: M1 D1 M2 D2 R T equal the rig's numbers to the last bit."""
    try:
        import cv2
    except ImportError:
        if os.environ.get("CI"):
            raise
        pytest.skip("opencv-python-headless is not installed (scripts/test.sh installs it)")
    rig = flatport.load_rig(EXAMPLE)
    path = tmp_path / "stereo.yml"
    path.write_text(rig.export_opencv())
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    assert storage.isOpened()
    left, right = rig.to_dict()["cameras"]
    for index, camera in ((1, left), (2, right)):
        matrix = storage.getNode(f"M{index}").mat()
        expected = [[camera["fx"], 0.0, camera["cx"]], [0.0, camera["fy"], camera["cy"]], [0.0, 0.0, 1.0]]
        assert matrix.dtype == np.float64 and np.array_equal(matrix, expected)
        distortion = storage.getNode(f"D{index}").mat().ravel()
        assert np.array_equal(distortion, camera.get("distortion", [0.0] * 5))
    rotation = storage.getNode("R").mat()
    translation = storage.getNode("T").mat().ravel()
    assert np.array_equal(rotation, right["rotation"])
    assert np.array_equal(translation, right["translation"])
    storage.release()


def surface_rig_dict():
    """The example rig without its glass: cameras above one bare, tilted water surface."""
    d = json.loads(EXAMPLE.read_text())
    d["interface"].pop("layers", None)
    return d


def surface_rig():
    return flatport.Rig.from_dict(surface_rig_dict())


def test_aquacal_binding_round_trips_and_equals_the_cli(tmp_path):
    rig = surface_rig()
    path = tmp_path / "calibration.json"
    text = rig.to_aquacal(path)
    assert path.read_text() == text
    written = json.loads(text)
    assert written["version"] == "1.0" and list(written["cameras"]) == rig.camera_names
    assert written["interface"]["normal"] == [0.0, 0.0, -1.0]
    back = flatport.Rig.from_aquacal(path)
    assert back.camera_names == rig.camera_names
    points = points_in_view(500, seed=23)
    for name in rig.camera_names:
        uv, status = rig.project(points, camera=name)
        uv_back, status_back = back.project(points, camera=name)
        np.testing.assert_array_equal(status, status_back)
        # The rig, written and read back, agrees to 1e-12 in its numbers: 1e-9 px.
        assert np.nanmax(np.abs(uv - uv_back)) < 1e-9
    # The second camera as master: the first then sits at minus the baseline.
    swapped = flatport.Rig.from_aquacal(path, master=rig.camera_names[1])
    assert swapped.camera_names == rig.camera_names[::-1]
    if flatport_binary() is not None:
        rig_path = tmp_path / "rig.json"
        # The same rig text as the binding's (a rig file written and read again may move the
        # rotation in its last bit).
        rig_path.write_text(json.dumps(surface_rig_dict()))
        subprocess.run([flatport_binary(), "export", "aquacal", "--rig", str(rig_path), "-o", str(tmp_path / "cli.json")], check=True, capture_output=True)
        assert (tmp_path / "cli.json").read_text() == text


def test_aquacal_binding_refuses_glass_and_bad_files(tmp_path):
    with pytest.raises(ValueError, match="bare water surface"):
        flatport.load_rig(EXAMPLE).to_aquacal()
    bad = tmp_path / "calibration.json"
    bad.write_text(surface_rig().to_aquacal().replace('"version": "1.0"', '"version": "0.9"'))
    with pytest.raises(ValueError, match="calibration.json: version"):
        flatport.Rig.from_aquacal(bad)
