#!/usr/bin/env python3
"""flatport's chessboard detector and OpenCV's findChessboardCornersSB side by side on a rendered
set with exact corners: per camera, the boards each found with every corner within 3 px of the
exact one (in whichever of the board's turns fits: a chessboard's corner 0 is a convention), and
the images only one of them got right.

    python3 scripts/chessboard_vs_opencv.py SET BOARD.json

SET is a calibration set `flatport render --calibration-set` wrote (`SET/water/<camera>/view_*.png`
with `SET/water/corners.json`); BOARD.json a chessboard ({"type": "chessboard", ...}). A board
cut by the image's edge has no exact corners for all its inner corners and counts for neither:
OpenCV then reports a grid of the board's shape over the part in view, one row or column off.
Needs numpy and OpenCV >= 4.14 and the flatport binary (FLATPORT_BIN, else target/release/flatport,
else flatport on PATH)."""
import json
import os
import pathlib
import shutil
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
FLAGS = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY


def binary():
    for candidate in [os.environ.get("FLATPORT_BIN"), ROOT / "target" / "release" / "flatport", shutil.which("flatport")]:
        if candidate and pathlib.Path(candidate).is_file():
            return str(candidate)
    sys.exit("no flatport binary: set FLATPORT_BIN or build target/release/flatport")


def main(set_dir, board):
    images_dir = pathlib.Path(set_dir) / "water"
    spec = json.loads(pathlib.Path(board).read_text())
    if spec.get("type") != "chessboard":
        sys.exit(f"{board}: not a chessboard (use scripts/charuco_vs_opencv.py for ChArUco boards)")
    size = (spec["squares_x"] - 1, spec["squares_y"] - 1)
    truth = json.loads((images_dir / "corners.json").read_text())
    flatport = binary()

    def ours(image):
        with tempfile.TemporaryDirectory() as scratch:
            out = pathlib.Path(scratch) / "o.json"
            subprocess.run([flatport, "detect", "--board", board, "-q", "-o", str(out), "--images", f"cam={image}"],
                           capture_output=True, text=True)
            if not out.is_file():
                return None
            views = json.loads(out.read_text())["views"]
            return views[0]["cam"] if views else None

    def theirs(image):
        ok, corners = cv2.findChessboardCornersSB(cv2.imread(str(image), cv2.IMREAD_GRAYSCALE), size, flags=FLAGS)
        return corners.reshape(-1, 2).tolist() if ok else None

    def right(found, n, cam):
        exact = truth["views"][n].get(cam)
        if found is None or exact is None or any(p is None for p in exact) or any(p is None for p in found):
            return False
        grid = np.array(found, float).reshape(size[1], size[0], 2)
        want = np.array(exact, float).reshape(size[1], size[0], 2)
        turns = [grid, grid[::-1], grid[:, ::-1], grid[::-1, ::-1]]
        return min(np.abs(g - want).max() for g in turns) < 3.0

    total = [0, 0]
    for cam in sorted(p.name for p in images_dir.iterdir() if p.is_dir()):
        images = sorted((images_dir / cam).glob("view_*.png"))
        with ThreadPoolExecutor(os.cpu_count()) as pool:
            a = [right(f, n, cam) for n, f in enumerate(pool.map(ours, images))]
        b = [right(theirs(i), n, cam) for n, i in enumerate(images)]
        whole = sum(truth["views"][n].get(cam) is not None and all(p is not None for p in truth["views"][n][cam])
                    for n in range(len(images)))
        print(f"{cam}: {len(images)} images, {whole} with the whole board in view; boards right flatport {sum(a)}, "
              f"OpenCV {sum(b)}; only OpenCV: {[n for n in range(len(images)) if b[n] and not a[n]]}; "
              f"only flatport: {[n for n in range(len(images)) if a[n] and not b[n]]}")
        total[0] += sum(a)
        total[1] += sum(b)
    print(f"all cameras: boards right flatport {total[0]}, OpenCV {cv2.__version__} {total[1]}")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2])
