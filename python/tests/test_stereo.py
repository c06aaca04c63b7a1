"""flatport.stereo on a pair rendered by the CLI (`flatport render --scene`): depths against the
renderer's exact depth maps (an independent oracle), the output shapes, bad input refused, and
the GPU (lavapipe without one) against the CPU. Needs the CLI ($FLATPORT_BIN, as scripts/test.sh
sets it)."""

import json
import os
import struct
import subprocess
import zlib
from pathlib import Path

import numpy as np
import pytest

import flatport

ROOT = Path(__file__).resolve().parents[2]
BIN = os.environ.get("FLATPORT_BIN", str(ROOT / "target" / "release" / "flatport"))


def read_grey_png(path):
    """An 8-bit grey, non-interlaced PNG (what `flatport render` writes) as float32 0 … 1."""
    data = Path(path).read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    at, idat, width, height = 8, b"", 0, 0
    while at < len(data):
        length, kind = struct.unpack(">I4s", data[at:at + 8])
        body = data[at + 8:at + 8 + length]
        if kind == b"IHDR":
            width, height, depth, colour, _, _, interlace = struct.unpack(">IIBBBBB", body)
            assert (depth, colour, interlace) == (8, 0, 0), "8-bit grey, not interlaced"
        elif kind == b"IDAT":
            idat += body
        at += 12 + length
    raw = zlib.decompress(idat)
    rows, previous = [], np.zeros(width, dtype=np.int32)
    for y in range(height):
        line = raw[y * (width + 1):(y + 1) * (width + 1)]
        kind, row = line[0], np.frombuffer(line[1:], dtype=np.uint8).astype(np.int32)
        out = np.zeros(width, dtype=np.int32)
        for x in range(width):
            a = out[x - 1] if x else 0
            b = previous[x]
            c = previous[x - 1] if x else 0
            if kind == 0:
                predictor = 0
            elif kind == 1:
                predictor = a
            elif kind == 2:
                predictor = b
            elif kind == 3:
                predictor = (a + b) // 2
            else:
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                predictor = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
            out[x] = (row[x] + predictor) & 0xFF
        rows.append(out)
        previous = out
    return np.array(rows, dtype=np.float32) / 255.0


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    folder = tmp_path_factory.mktemp("seabed")
    subprocess.run(
        [BIN, "render", "--scene", str(ROOT / "data/scenes/seabed.json"), "--rig",
         str(ROOT / "data/rigs/small_stereo.json"), "--noise", "2", "--device", "cpu", "--quiet",
         "-o", str(folder)],
        check=True,
    )
    rig = flatport.load_rig(str(folder / "rig.json"))
    images = [read_grey_png(folder / c / "frame_000.png") for c in ("left", "right")]
    truth = np.load(folder / "left" / "depth_000.npy")
    return rig, images, truth


def test_depths_match_the_renderers_truth(pair):
    rig, images, truth = pair
    result = flatport.stereo(rig, images, depth=(1.0, 2.2), hypotheses=64, device="cpu")
    assert result.depth.shape == (256, 320) and result.points.shape == (256, 320, 3)
    assert result.confidence.shape == (256, 320) and result.device == "cpu"
    ok = np.isfinite(result.depth) & np.isfinite(truth)
    assert ok.mean() > 0.5
    error = np.abs(result.depth[ok] - truth[ok]) / truth[ok]
    assert np.median(error) < 0.005, np.median(error)
    assert np.array_equal(np.isfinite(result.depth), np.isfinite(result.points[..., 0]))


def test_bad_input_is_refused(pair):
    rig, images, _ = pair
    with pytest.raises(ValueError, match="images for the rig"):
        flatport.stereo(rig, images[:1], depth=(1.0, 2.2))
    with pytest.raises(ValueError, match="device"):
        flatport.stereo(rig, images, device="tpu")
    with pytest.raises(ValueError, match="finite"):
        flatport.stereo(rig, [images[0], np.full_like(images[1], np.nan)])


def test_gpu_agrees_with_the_cpu(pair):
    rig, images, _ = pair
    try:
        gpu = flatport.stereo(rig, images, depth=(1.0, 2.2), hypotheses=32, device="gpu")
    except RuntimeError as error:
        if os.environ.get("CI"):
            raise
        pytest.skip(f"no Vulkan adapter: {error}")
    cpu = flatport.stereo(rig, images, depth=(1.0, 2.2), hypotheses=32, device="cpu")
    both = np.isfinite(cpu.depth) & np.isfinite(gpu.depth)
    assert (np.isfinite(cpu.depth) == np.isfinite(gpu.depth)).mean() >= 0.98
    step = (1 / 1.0 - 1 / 2.2) / 31
    steps = np.abs(1 / cpu.depth[both] - 1 / gpu.depth[both]) / step
    assert (steps <= 0.25).mean() >= 0.99


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    """Two frames of the water-surface scene at the small rig's size, rendered by the CLI."""
    folder = tmp_path_factory.mktemp("surface")
    subprocess.run(
        [BIN, "render", "--scene", str(ROOT / "data/scenes/water_surface.json"), "--rig",
         str(ROOT / "data/rigs/small_stereo.json"), "--noise", "2", "--device", "cpu", "--quiet",
         "-o", str(folder)],
        check=True,
    )
    return flatport.load_rig(str(folder / "rig.json")), folder


def test_frames_of_a_sequence_are_what_stereo_gives_each_frame(sequence):
    rig, folder = sequence
    options = dict(depth=(1.0, 2.0), hypotheses=32, device="cpu")
    frames = list(flatport.stereo_frames(rig, folder, frames="1:", **options))
    assert [(f.name, f.index) for f in frames] == [("frame_001", 1)]
    images = [read_grey_png(folder / c / "frame_001.png") for c in ("left", "right")]
    alone = flatport.stereo(rig, images, **options)
    assert np.array_equal(frames[0].depth, alone.depth, equal_nan=True)
    assert np.array_equal(frames[0].points, alone.points, equal_nan=True)
    assert np.array_equal(frames[0].confidence, alone.confidence)
    every = [f.name for f in flatport.stereo_frames(rig, str(folder), frames=slice(None, None, 1), **options)]
    assert every == ["frame_000", "frame_001"]


def test_a_bad_sequence_is_refused_before_any_frame(sequence, tmp_path):
    rig, folder = sequence
    with pytest.raises(ValueError, match="has 2 frames"):
        flatport.stereo_frames(rig, folder, frames="5:")
    with pytest.raises(ValueError, match="missing"):
        flatport.stereo_frames(rig, tmp_path)
    with pytest.raises(ValueError, match="frames"):
        flatport.stereo_frames(rig, folder, frames=slice(-1, None))


def test_a_fused_cloud_reads_in_plyfile(sequence, tmp_path):
    """The CLI's --fuse cloud, read by plyfile (a maintained reader outside the crate)."""
    plyfile = pytest.importorskip("plyfile", reason="pip install plyfile to read the PLY back")
    rig, folder = sequence
    out = tmp_path / "fused"
    subprocess.run(
        [BIN, "stereo", "--rig", str(folder / "rig.json"), "--images", str(folder), "--output",
         str(out), "--depth", "1.0:2.0", "--hypotheses", "32", "--device", "cpu", "--frames", "0",
         "--fuse", "--quiet"],
        check=True,
    )
    vertex = plyfile.PlyData.read(str(out / "frame_000" / "fused.ply"))["vertex"]
    assert [p.name for p in vertex.properties] == ["x", "y", "z", "nx", "ny", "nz", "red", "green", "blue"]
    record = json.loads((out / "frame_000" / "frame.json").read_text())
    assert len(vertex.data) == record["fused_points"] > 1000
    xyz = np.stack([vertex["x"], vertex["y"], vertex["z"]], axis=1)
    normals = np.stack([vertex["nx"], vertex["ny"], vertex["nz"]], axis=1)
    assert np.isfinite(xyz).all() and np.allclose(np.linalg.norm(normals, axis=1), 1, atol=1e-5)
    # The seabed lies 1.44–1.56 m deep, the sphere from 1.18 m: the points lie between.
    assert 1.1 < xyz[:, 2].min() and xyz[:, 2].max() < 1.7
    # Facing the cameras (above the scene, looking down +z): normals point up, −z, mostly.
    assert (normals[:, 2] < 0).mean() > 0.95
