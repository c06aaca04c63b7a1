#!/usr/bin/env python3
"""Golden oracle for the in-air intrinsics stage (src/calib/pipeline/intrinsics.rs).

Makes a synthetic single-camera calibration data set and calibrates it with OpenCV's
``cv2.calibrateCameraExtended``, outside the crate; tests/intrinsics.rs reads the JSON it writes
and holds the crate's estimate to OpenCV's on the SAME corners.

The scene (deterministic, numpy ``RandomState(SEED)``):
- camera 1280x1024, fx 1000, fy 1002, cx 645.3, cy 508.7, distortion [k1, k2, p1, p2, k3] =
  [-0.2, 0.1, 1e-3, -5e-4, 0] (k3 is zero: a lens the 4-coefficient model describes exactly);
- a 9x6 inner-corner board (rows 6, cols 9), 40 mm squares, corner r*cols + c at (c*s, r*s, 0);
- 15 views at 0.45-0.9 m, tilted up to about 40 degrees about random axes, placed over the whole
  image so that several views lose corners beyond the image border (dropped: partial views);
- Gaussian noise of 0.2 px per coordinate.

Corners are projected with ``cv2.projectPoints`` (OpenCV's own lens model, the convention the
crate follows). OpenCV works in float32 on the corners, so the noisy corners are rounded to
float32 before OpenCV sees them, and the JSON stores exactly those values: both estimators get
identical input. The noise-free corners are stored in full double precision as well (for the
exactness test; OpenCV does not see them).

OpenCV is run twice, with every flag off (k1, k2, p1, p2, k3 free) and with CALIB_FIX_K3, to
convergence (COUNT+EPS, 1000 iterations, eps 1e-15). Its sigma are stdDeviationsIntrinsics
(OpenCV >= 4.8: sigma^2 = SSR / (2N - p), p counting intrinsics and poses).

How it was run (from the repository root):

    python3 -m venv target/venv
    target/venv/bin/pip install opencv-python-headless==4.14.0.94
    target/venv/bin/python scripts/opencv_intrinsics.py > tests/golden/opencv_intrinsics.json

Deterministic (OpenCV on one thread): the same OpenCV and numpy give the same file.
"""

import json
import sys

import cv2
import numpy as np

SEED = 20261205
WIDTH, HEIGHT = 1280, 1024
FX, FY, CX, CY = 1000.0, 1002.0, 645.3, 508.7
DIST = [-0.2, 0.1, 1e-3, -5e-4, 0.0]
ROWS, COLS, SQUARE = 6, 9, 0.04
VIEWS = 15
NOISE_PX = 0.2
MIN_CORNERS = 12


def board_points():
    return np.array(
        [[c * SQUARE, r * SQUARE, 0.0] for r in range(ROWS) for c in range(COLS)], dtype=np.float64
    )


def rotation(axis, angle):
    axis = axis / np.linalg.norm(axis)
    rvec = (axis * angle).reshape(3, 1)
    r, _ = cv2.Rodrigues(rvec)
    return r


def make_views(rng, k, dist):
    """Board poses (rvec, tvec) and projected corners; each view keeps its in-image corners."""
    obj = board_points()
    centre = obj.mean(axis=0)
    views = []
    while len(views) < VIEWS:
        depth = rng.uniform(0.45, 0.9)
        # Aim the board centre at a random pixel over the whole image, out to its edges, so
        # some views hang over the border.
        u = rng.uniform(0.05, 0.95) * WIDTH
        v = rng.uniform(0.05, 0.95) * HEIGHT
        ray = np.linalg.solve(k, np.array([u, v, 1.0]))
        target = ray / ray[2] * depth
        tilt = np.deg2rad(rng.uniform(10.0, 40.0))
        axis = np.array([rng.normal(), rng.normal(), 0.2 * rng.normal()])
        spin = rotation(np.array([0.0, 0.0, 1.0]), rng.uniform(-0.4, 0.4))
        r = rotation(axis, tilt) @ spin
        t = target - r @ centre
        rvec, _ = cv2.Rodrigues(r)
        clean, _ = cv2.projectPoints(obj, rvec, t.reshape(3, 1), k, dist)
        clean = clean.reshape(-1, 2)
        # Every corner must be in front of the camera (the board never crosses z = 0 here).
        if np.any((r @ obj.T + t.reshape(3, 1))[2] <= 0.05):
            continue
        inside = (
            (clean[:, 0] >= 0)
            & (clean[:, 0] <= WIDTH - 1)
            & (clean[:, 1] >= 0)
            & (clean[:, 1] <= HEIGHT - 1)
        )
        ids = np.nonzero(inside)[0]
        if len(ids) < MIN_CORNERS:
            continue
        noisy = clean[ids] + rng.normal(0.0, NOISE_PX, size=(len(ids), 2))
        noisy = noisy.astype(np.float32)
        views.append(
            {
                "label": f"view{len(views):02d}.png",
                "ids": [int(i) for i in ids],
                "noisy": noisy,
                "clean": clean[ids],
                "rvec": rvec.ravel().tolist(),
                "tvec": t.tolist(),
            }
        )
    return views


def calibrate(views, flags):
    obj = board_points().astype(np.float32)
    object_points = [obj[v["ids"]].reshape(-1, 1, 3) for v in views]
    image_points = [v["noisy"].reshape(-1, 1, 2) for v in views]
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 1000, 1e-15)
    (rms, k, dist, _rvecs, _tvecs, std_intrinsics, _std_extrinsics, per_view) = (
        cv2.calibrateCameraExtended(
            object_points, image_points, (WIDTH, HEIGHT), None, None, flags=flags, criteria=criteria
        )
    )
    dist = dist.ravel().tolist() + [0.0] * 5
    std = std_intrinsics.ravel().tolist()
    return {
        "flags": int(flags),
        "rms_px": float(rms),
        "fx": float(k[0, 0]),
        "fy": float(k[1, 1]),
        "cx": float(k[0, 2]),
        "cy": float(k[1, 2]),
        "distortion": dist[:5],
        # fx, fy, cx, cy, k1, k2, p1, p2, k3 (OpenCV's stdDeviationsIntrinsics, first nine).
        "std": std[:9],
        "view_rms_px": [float(e) for e in per_view.ravel()],
    }


def main():
    # One thread: OpenCV's threaded sums otherwise change the last digits from run to run.
    cv2.setNumThreads(1)
    rng = np.random.RandomState(SEED)
    k = np.array([[FX, 0.0, CX], [0.0, FY, CY], [0.0, 0.0, 1.0]])
    dist = np.array(DIST)
    views = make_views(rng, k, dist)
    full = calibrate(views, 0)
    fix_k3 = calibrate(views, cv2.CALIB_FIX_K3)
    out = {
        "generator": "scripts/opencv_intrinsics.py",
        "opencv": cv2.__version__,
        "numpy": np.__version__,
        "seed": SEED,
        "width": WIDTH,
        "height": HEIGHT,
        "board": {"rows": ROWS, "cols": COLS, "square": SQUARE},
        "noise_px": NOISE_PX,
        "truth": {"fx": FX, "fy": FY, "cx": CX, "cy": CY, "distortion": DIST},
        "views": [
            {
                "label": v["label"],
                "ids": v["ids"],
                # float32 values written as the doubles they equal: what OpenCV saw.
                "corners": [[float(u), float(w)] for u, w in v["noisy"]],
                "clean": [[float(u), float(w)] for u, w in v["clean"]],
                "rvec": v["rvec"],
                "tvec": v["tvec"],
            }
            for v in views
        ],
        "opencv_full": full,
        "opencv_fix_k3": fix_k3,
    }
    json.dump(out, sys.stdout, indent=1)
    sys.stdout.write("\n")


if __name__ == "__main__":
    main()
