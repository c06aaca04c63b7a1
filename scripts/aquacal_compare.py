#!/usr/bin/env python3
"""Compare calibrated rigs against the true rig of a rendered calibration set.

Used by scripts/aquacal_side_by_side.sh (not run in CI). Every rig is a flatport rig file
(docs/rigs.md): camera k maps the master's frame to its own, x_k = R_k x_master + t_k, and the
shared interface is the plane n . x = distance in the master's frame. The rigs may have different
masters (flatport's `calibrate --images` takes the first camera folder by name, AquaCal's file
starts with its own order), so every figure is taken in the TRUE rig's master frame, cameras
matched by name.

Figures, per calibrated rig:
  - extrinsics: each camera's rotation (deg) and translation (mm) relative to the true master,
    against the truth (the largest over the cameras, and each camera's);
  - water surface: the signed error of its distance from the true master's centre (mm) and the
    angle of its normal (deg);
  - in-air lens: the largest pixel displacement over the image between the calibrated and the
    true lens (K and distortion) for the same ray (a 41 x 33 grid of pixels over the image,
    undistorted through the true lens by OpenCV's iterative undistortPointsIter, then projected
    through both lenses by OpenCV's projectPoints);
  - 3-D: points on a grid under water, projected to exact pixels through the TRUE rig by
    `flatport project`, triangulated with the calibrated rig by `flatport triangulate` for each
    pair of cameras that sees them; the median error as a % of the point's distance from the
    pair's mid-point. The true rig triangulates the same pixels first as a check of the plumbing.

Usage: aquacal_compare.py FLATPORT TRUE_RIG.json NAME=RIG.json [NAME=RIG.json ...] [--json OUT]
"""

import itertools
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np


def load_rig(path):
    """Cameras by name: (K, dist, size, R, t) from the master, and the plane (n, d)."""
    rig = json.loads(Path(path).read_text())
    cams = {}
    for c in rig["cameras"]:
        k = np.array([[c["fx"], 0, c["cx"]], [0, c["fy"], c["cy"]], [0, 0, 1]], float)
        dist = np.zeros(5)
        d = c.get("distortion", [])
        dist[: len(d)] = d
        r = np.array(c.get("rotation", np.eye(3)), float)
        t = np.array(c.get("translation", [0, 0, 0]), float)
        cams[c["name"]] = dict(K=k, dist=dist, size=(c["width"], c["height"]), R=r, t=t)
    if "interface" not in rig:
        sys.exit(f"{path}: only one shared interface is compared (no 'interface')")
    i = rig["interface"]
    n = np.array(i["normal"], float)
    n /= np.linalg.norm(n)
    return dict(
        names=[c["name"] for c in rig["cameras"]], cams=cams, n=n, d=float(i["distance"])
    )


def in_frame_of(rig, ref):
    """The rig re-expressed in the frame of its camera `ref`: cameras' (R, t) and the plane."""
    r0, t0 = rig["cams"][ref]["R"], rig["cams"][ref]["t"]
    out = {}
    for name, c in rig["cams"].items():
        r = c["R"] @ r0.T
        out[name] = (r, c["t"] - r @ t0)
    n = r0 @ rig["n"]
    return out, n, rig["d"] + n @ t0


def rot_angle_deg(a, b):
    c = (np.trace(a @ b.T) - 1) / 2
    return float(np.degrees(np.arccos(np.clip(c, -1, 1))))


def lens_displacement_px(true_cam, cam):
    w, h = true_cam["size"]
    u, v = np.meshgrid(np.linspace(0, w - 1, 41), np.linspace(0, h - 1, 33))
    px = np.stack([u.ravel(), v.ravel()], 1).reshape(-1, 1, 2).astype(np.float64)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14)
    xy = cv2.undistortPointsIter(px, true_cam["K"], true_cam["dist"], None, None, crit)
    rays = np.concatenate([xy.reshape(-1, 2), np.ones((xy.shape[0], 1))], 1)
    zero = np.zeros(3)
    p_true, _ = cv2.projectPoints(rays, zero, zero, true_cam["K"], true_cam["dist"])
    p_cal, _ = cv2.projectPoints(rays, zero, zero, cam["K"], cam["dist"])
    return float(np.max(np.linalg.norm(p_true - p_cal, axis=2)))


def run(cmd):
    return subprocess.run(cmd, check=True, capture_output=True, text=True).stdout


def read_csv(text):
    lines = [l for l in text.strip().splitlines()[1:] if l.strip()]
    return np.array([[float(x) for x in l.split(",")] for l in lines])


def main():
    args = sys.argv[1:]
    out_json = None
    if "--json" in args:
        i = args.index("--json")
        out_json = args[i + 1]
        del args[i : i + 2]
    flatport, true_path, calibrated = args[0], args[1], args[2:]
    truth = load_rig(true_path)
    master = truth["names"][0]
    t_cams, t_n, t_d = in_frame_of(truth, master)
    centres = {k: -r.T @ t for k, (r, t) in t_cams.items()}

    tmp = Path(tempfile.mkdtemp(prefix="aquacal_compare_"))
    # Points under the water, in the true master's frame, seen by every camera.
    g = np.linspace(-0.05, 0.20, 8)
    pts = np.array([[x, y, z] for x in g for y in g for z in np.linspace(0.4, 0.9, 6)])
    pts_csv = tmp / "points.csv"
    pts_csv.write_text("x,y,z\n" + "".join(f"{p[0]:.17g},{p[1]:.17g},{p[2]:.17g}\n" for p in pts))
    pixels = {}
    keep = np.ones(len(pts), bool)
    for name in truth["names"]:
        uv = read_csv(run([flatport, "project", "--rig", true_path, "--points", str(pts_csv),
                           "--camera", name, "--device", "cpu"]))
        w, h = truth["cams"][name]["size"]
        keep &= (uv[:, 0] >= 0) & (uv[:, 1] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] <= h - 1)
        pixels[name] = uv
    pts = pts[keep]
    pixels = {k: v[keep] for k, v in pixels.items()}
    pairs = list(itertools.combinations(truth["names"], 2))

    def triangulate_errors(rig_path, rig):
        cams, _, _ = in_frame_of(rig, master)
        # The rig's master frame -> the true master's frame (through the rig's own camera `master`).
        r_m, t_m = rig["cams"][master]["R"], rig["cams"][master]["t"]
        errs = []
        for a, b in pairs:
            m = tmp / f"{a}_{b}.csv"
            m.write_text("ul,vl,ur,vr\n" + "".join(
                f"{pa[0]:.17g},{pa[1]:.17g},{pb[0]:.17g},{pb[1]:.17g}\n"
                for pa, pb in zip(pixels[a], pixels[b])))
            xyz = read_csv(run([flatport, "triangulate", "--rig", rig_path, "--matches", str(m),
                                "--cameras", f"{a},{b}", "--device", "cpu"]))[:, :3]
            in_master = xyz @ r_m.T + t_m
            mid = (centres[a] + centres[b]) / 2
            errs += list(np.linalg.norm(in_master - pts, axis=1)
                         / np.linalg.norm(pts - mid, axis=1) * 100)
        return np.array(errs)

    check = triangulate_errors(true_path, truth)
    results = {"points": int(len(pts)), "pairs": len(pairs),
               "true_rig_triangulation_max_pct": float(np.max(check)), "rigs": {}}
    if np.max(check) > 1e-6:
        sys.exit(f"the true rig triangulates its own pixels {np.max(check)} % off: plumbing bug")

    for item in calibrated:
        label, path = item.split("=", 1)
        rig = load_rig(path)
        cams, n, d = in_frame_of(rig, master)
        per_cam = {}
        for name in truth["names"]:
            r, t = cams[name]
            tr, tt = t_cams[name]
            per_cam[name] = dict(
                rotation_deg=rot_angle_deg(r, tr),
                translation_mm=float(np.linalg.norm(t - tt) * 1e3),
                lens_px=lens_displacement_px(truth["cams"][name], rig["cams"][name]),
            )
        errs = triangulate_errors(path, rig)
        results["rigs"][label] = dict(
            rig=path,
            max_rotation_deg=max(c["rotation_deg"] for c in per_cam.values()),
            max_translation_mm=max(c["translation_mm"] for c in per_cam.values()),
            surface_height_mm=float((d - t_d) * 1e3),
            surface_normal_deg=float(np.degrees(np.arccos(np.clip(n @ t_n, -1, 1)))),
            max_lens_px=max(c["lens_px"] for c in per_cam.values()),
            median_3d_pct=float(np.median(errs)),
            p95_3d_pct=float(np.percentile(errs, 95)),
            cameras=per_cam,
        )

    print(f"{len(pts)} points under water seen by every camera, {len(pairs)} pairs; "
          f"the true rig triangulates them within {results['true_rig_triangulation_max_pct']:.1e} %")
    print(f"{'':10} {'rot deg':>9} {'trans mm':>9} {'surface mm':>11} {'normal deg':>11} "
          f"{'lens px':>8} {'3-D med %':>10} {'3-D p95 %':>10}")
    for label, r in results["rigs"].items():
        print(f"{label:10} {r['max_rotation_deg']:9.4f} {r['max_translation_mm']:9.3f} "
              f"{r['surface_height_mm']:+11.3f} {r['surface_normal_deg']:11.4f} "
              f"{r['max_lens_px']:8.3f} {r['median_3d_pct']:10.4f} {r['p95_3d_pct']:10.4f}")
    if out_json:
        Path(out_json).write_text(json.dumps(results, indent=1) + "\n")


if __name__ == "__main__":
    main()
