#!/usr/bin/env python3
"""flatport's ChArUco detector and OpenCV's side by side on a rendered set with exact corners:
per camera, the boards found, the corners found, the corner RMS against the exact corners over
the ids both found, and images where one of flatport's corners is over 3 px off (a mislabel);
then both detectors' time over the whole set.

    python3 scripts/charuco_vs_opencv.py SET BOARD.json

SET is a folder `flatport render` wrote: `SET/water/<camera>/view_*.png` with
`SET/water/corners.json` (a calibration set), or `SET/<camera>/view_*.png` with
`SET/corners.json`. Needs numpy and OpenCV >= 4.14 (opencv-python-headless) and the flatport
binary (FLATPORT_BIN, else target/release/flatport, else flatport on PATH). Each image is
detected by `flatport detect` alone (so the image a result belongs to is never in doubt); the
time is one `flatport detect` over every camera's images, against cv2.aruco.CharucoDetector over
the same images (decoded beforehand), both on all cores."""
import json
import math
import os
import pathlib
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor

import cv2

ROOT = pathlib.Path(__file__).resolve().parents[1]


def binary():
    for candidate in [os.environ.get("FLATPORT_BIN"), ROOT / "target" / "release" / "flatport", shutil.which("flatport")]:
        if candidate and pathlib.Path(candidate).is_file():
            return str(candidate)
    sys.exit("no flatport binary: set FLATPORT_BIN or build target/release/flatport")


def opencv_detector(spec):
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, spec["dictionary"]))
    board = cv2.aruco.CharucoBoard((spec["squares_x"], spec["squares_y"]), spec["square_size"], spec["marker_size"], dictionary)
    board.setLegacyPattern(bool(spec.get("legacy_pattern", False)))
    return cv2.aruco.CharucoDetector(board)


def main(set_dir, board):
    set_dir = pathlib.Path(set_dir)
    images_dir = set_dir / "water" if (set_dir / "water").is_dir() else set_dir
    truth = json.loads((images_dir / "corners.json").read_text())
    spec = json.loads(pathlib.Path(board).read_text())
    count = (spec["squares_x"] - 1) * (spec["squares_y"] - 1)
    detector = opencv_detector(spec)
    flatport = binary()
    scratch = pathlib.Path(tempfile.mkdtemp())

    def ours(image):
        out = scratch / f"{image.parent.name}_{image.stem}.json"
        run = subprocess.run([flatport, "detect", "--board", board, "--images", f"cam={image}", "-o", str(out), "-q"],
                             capture_output=True, text=True)
        if run.returncode != 0 or not out.is_file():
            return None
        views = json.loads(out.read_text())["views"]
        return views[0]["cam"] if views else None

    def theirs(gray):
        corners, ids, _, _ = detector.detectBoard(gray)
        if ids is None or len(ids) < 4:
            return None
        found = [None] * count
        for i, p in zip(ids.ravel(), corners.reshape(-1, 2)):
            found[int(i)] = [float(p[0]), float(p[1])]
        return found

    def rms(values):
        return math.sqrt(sum(v * v for v in values) / len(values)) if values else float("nan")

    cameras = sorted(p.name for p in images_dir.iterdir() if p.is_dir())
    total = {"boards": [0, 0], "corners": [0, 0], "errors": [[], []]}
    grays = {}
    for cam in cameras:
        images = sorted((images_dir / cam).glob("view_*.png"))
        grays[cam] = [cv2.imread(str(i), cv2.IMREAD_GRAYSCALE) for i in images]
        with ThreadPoolExecutor(os.cpu_count()) as pool:
            found = list(pool.map(ours, images))
        opencv = [theirs(g) for g in grays[cam]]
        errors, corners, off = ([], []), [0, 0], 0
        for n, (a, b) in enumerate(zip(found, opencv)):
            # A camera the board is out of view of in this frame has no exact corners: any
            # corner found there is off.
            exact = truth["views"][n].get(cam) or [None] * count
            if a is not None and not any(exact):
                off += 1
            if a is not None:
                corners[0] += sum(p is not None for p in a)
                off += any(math.hypot(p[0] - q[0], p[1] - q[1]) > 3 for p, q in zip(a, exact) if p and q)
            if b is not None:
                corners[1] += sum(p is not None for p in b)
            if a is not None and b is not None:
                for i in range(count):
                    if a[i] and b[i] and exact[i]:
                        errors[0].append(math.hypot(a[i][0] - exact[i][0], a[i][1] - exact[i][1]))
                        errors[1].append(math.hypot(b[i][0] - exact[i][0], b[i][1] - exact[i][1]))
        boards = [sum(a is not None for a in found), sum(b is not None for b in opencv)]
        print(f"{cam}: {len(images)} images; boards flatport {boards[0]}, OpenCV {boards[1]}; corners {corners[0]}, "
              f"{corners[1]}; RMS over the {len(errors[0])} corners both found {rms(errors[0]):.3f} px, {rms(errors[1]):.3f} px; "
              f"images with a flatport corner over 3 px off (or the board found where it is out of view): {off}")
        for j in range(2):
            total["boards"][j] += boards[j]
            total["corners"][j] += corners[j]
            total["errors"][j] += errors[j]
    print(f"all cameras: boards flatport {total['boards'][0]}, OpenCV {total['boards'][1]}; corners {total['corners'][0]}, "
          f"{total['corners'][1]}; RMS {rms(total['errors'][0]):.3f} px, {rms(total['errors'][1]):.3f} px")
    command = [flatport, "detect", "--board", board, "-o", str(scratch / "all.json"), "-q"]
    for cam in cameras:
        command += ["--images", f"{cam}={images_dir / cam}/view_*.png"]
    started = time.perf_counter()
    run = subprocess.run(command, capture_output=True, text=True)
    ours_s = time.perf_counter() - started
    if run.returncode != 0:
        print(f"flatport detect over the whole set exited with {run.returncode}: {run.stderr.strip()[-300:]}")
    started = time.perf_counter()
    for cam in cameras:
        for gray in grays[cam]:
            detector.detectBoard(gray)
    theirs_s = time.perf_counter() - started
    print(f"time over {sum(len(g) for g in grays.values())} images: flatport detect {ours_s:.2f} s, "
          f"OpenCV {cv2.__version__} CharucoDetector {theirs_s:.2f} s ({cv2.getNumThreads()} threads)")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2])
