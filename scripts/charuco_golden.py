#!/usr/bin/env python3
"""OpenCV's ChArUco boards as the oracle for flatport's boards (tests/charuco.rs).

Writes tests/golden/charuco/:
- flat_<name>.png: cv2.aruco.CharucoBoard(...).generateImage at whole pixels per marker bit
  cell, so every pixel is one colour: the pattern flatport renders must equal it pixel for pixel
  (squares, marker placement, marker ids, bit order, colour parity).
- view_<name>.png: the 7x5 board warped in perspective (a pinhole camera's view of the board,
  8x supersampled then box-filtered: cv2.INTER_AREA), one whole, one crossing the image edge.
- charuco.json: the boards, and per view the exact position of every ChArUco corner (id, u, v)
  that lies inside the image, from the homography that made the view (OpenCV's
  getChessboardCorners mapped through it), plus what OpenCV's own CharucoDetector found on the
  view (ids and RMS against the exact corners), for the record.

Pixel convention (flatport, OpenCV): (0, 0) is the centre of the top-left pixel.

Run with OpenCV 4.14 (pip install opencv-python-headless==4.14.0.94 numpy):
    python3 scripts/charuco_golden.py tests/golden/charuco
"""
import json
import os
import sys

import cv2
import numpy as np

OUT = sys.argv[1] if len(sys.argv) > 1 else "tests/golden/charuco"
os.makedirs(OUT, exist_ok=True)

# Flat boards: (name, squares_x, squares_y, dictionary, px per square, px per marker side).
# Markers are (bits + 2) cells wide, each a whole number of pixels.
FLAT = [
    ("7x5_4x4_50", 7, 5, "DICT_4X4_50", 48, 36),  # 6 cells of 6 px
    ("5x6_5x5_100", 5, 6, "DICT_5X5_100", 40, 28),  # 7 cells of 4 px; 6 rows: even
]


def board(sx, sy, square, marker, dictionary):
    d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    return cv2.aruco.CharucoBoard((sx, sy), square, marker, d)


golden = {"opencv": cv2.__version__, "flat": [], "views": []}
for name, sx, sy, dictionary, px, marker_px in FLAT:
    margin = px  # one square of white margin
    b = board(sx, sy, float(px), float(marker_px), dictionary)
    image = b.generateImage((sx * px + 2 * margin, sy * px + 2 * margin), marginSize=margin, borderBits=1)
    path = f"flat_{name}.png"
    cv2.imwrite(os.path.join(OUT, path), image)
    golden["flat"].append({
        "file": path, "squares_x": sx, "squares_y": sy, "dictionary": dictionary,
        "px_per_square": px, "marker_px": marker_px, "margin_px": margin,
    })

# Perspective views of the 7x5 DICT_4X4_50 board, 40 mm squares, 30 mm markers.
SX, SY, SQUARE, MARKER, DICT = 7, 5, 0.04, 0.03, "DICT_4X4_50"
b = board(SX, SY, SQUARE, MARKER, DICT)
PX = 160  # source pixels per square
MARGIN = PX
src = b.generateImage((SX * PX + 2 * MARGIN, SY * PX + 2 * MARGIN), marginSize=MARGIN, borderBits=1)
# Board metres -> source pixel centres.
src_from_board = np.array([[PX / SQUARE, 0, MARGIN - 0.5], [0, PX / SQUARE, MARGIN - 0.5], [0, 0, 1.0]])
W, H, S = 640, 480, 8
K = np.array([[600.0, 0, 319.5], [0, 600.0, 239.5], [0, 0, 1]])
corners_board = b.getChessboardCorners()[:, :2]  # id order, metres from the board's top-left


def rot(rx, ry, rz):
    return cv2.Rodrigues(np.array([rx, ry, rz], dtype=np.float64))[0]


# (name, rotation (rad), translation (m)): camera-from-board; board z points away from the camera.
VIEWS = [
    ("whole", (0.35, -0.45, 0.12), (-0.13, -0.08, 0.48)),
    ("partial", (-0.25, 0.3, -0.2), (-0.03, -0.08, 0.36)),
]
for name, r, t in VIEWS:
    R = rot(*r)
    img_from_board = K @ np.column_stack([R[:, 0], R[:, 1], np.array(t)])
    big_from_small = np.array([[S, 0, (S - 1) / 2], [0, S, (S - 1) / 2], [0, 0, 1.0]])
    big_from_src = big_from_small @ img_from_board @ np.linalg.inv(src_from_board)
    big = cv2.warpPerspective(src, big_from_src, (W * S, H * S), flags=cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=100)
    small = cv2.resize(big, (W, H), interpolation=cv2.INTER_AREA)
    path = f"view_{name}.png"
    cv2.imwrite(os.path.join(OUT, path), small)
    p = (img_from_board @ np.column_stack([corners_board, np.ones(len(corners_board))]).T).T
    uv = p[:, :2] / p[:, 2:]
    inside = (uv[:, 0] >= 0) & (uv[:, 1] >= 0) & (uv[:, 0] <= W - 1) & (uv[:, 1] <= H - 1)
    exact = [[i, float(uv[i, 0]), float(uv[i, 1])] for i in range(len(uv)) if inside[i]]
    # OpenCV's own detector on the same image, for the record.
    detector = cv2.aruco.CharucoDetector(b)
    ch_corners, ch_ids, _, _ = detector.detectBoard(small)
    found = {}
    if ch_ids is not None:
        for (u, v), i in zip(ch_corners.reshape(-1, 2), ch_ids.ravel()):
            found[int(i)] = (float(u), float(v))
    errors = [np.hypot(found[i][0] - uv[i, 0], found[i][1] - uv[i, 1]) for i in found]
    wrong = [i for i in found if errors[list(found).index(i)] > 2.0]
    assert not wrong, f"{name}: OpenCV's ids disagree with the exact corners at {wrong}"
    golden["views"].append({
        "file": path, "width": W, "height": H,
        "board": {"type": "charuco", "squares_x": SX, "squares_y": SY, "square_size": SQUARE,
                  "marker_size": MARKER, "dictionary": DICT, "legacy_pattern": False},
        "corners": exact,
        "opencv_found_ids": sorted(found),
        "opencv_rms_px": float(np.sqrt(np.mean(np.square(errors)))) if errors else None,
    })
    print(f"{name}: {len(exact)} corners in the image; OpenCV found {len(found)}, "
          f"RMS {golden['views'][-1]['opencv_rms_px']}")

with open(os.path.join(OUT, "charuco.json"), "w") as f:
    json.dump(golden, f, indent=1)
    f.write("\n")
