#!/usr/bin/env python3
"""Golden values for flatport's refractive model from 50-digit arithmetic (mpmath).

How it was run:  python3 scripts/golden.py    (Python 3.11.7, mpmath 1.3.0; `pip install mpmath`)
It writes tests/golden/{rigs.json, project.csv, backproject.csv, vop.csv}, which
tests/golden_values.rs reads. It is deterministic: rerunning it must leave the files unchanged.

Nothing here comes from flatport. At 50 significant digits the script
  - traces rays plane by plane with Snell's law in angle form (tangential component,
    sin θ₂ = μ1/μ2 · sin θ₁),
  - projects points by bisection on the angle of incidence in the plane of refraction (the lateral
    miss at the point's depth is increasing in the angle) to a bracket below 1e-45 rad, then applies
    the pinhole and the OpenCV distortion [k1, k2, p1, p2, k3],
  - back-projects pixels by undistorting with Newton's method (analytic Jacobian) and tracing,
  - finds Virtual Object Points by intersecting the backward extension of the air ray with the
    object axis (the line through the point parallel to the normal) -- never from eq 4.8.

Inputs are the binary64 values of the decimals written in rigs.json and the CSV files (so the
golden values belong to exactly the numbers the Rust test reads), except the rotation matrices,
which are exact decimal rotations (Pythagorean cosine/sine pairs) used as written.

Conventions (DESIGN.md): OpenCV camera frame, X_cam = R·X_master + t, C = −Rᵀt; n points into
the water; interface i lies on n·X = d + t_1 + … + t_(i−1); x̌ is the signed distance from A1 (where
the object axis meets the outer interface) to the VOP, positive toward the water. A rig's "water"
is its last medium (air again for the tank).
"""

import json
import os
import re

from mpmath import mp, mpf

mp.dps = 50

HERE = os.path.dirname(os.path.abspath(__file__))
OUT = os.path.join(HERE, "..", "tests", "golden")

# Exact decimal rotations: 0.99712² + 0.07584² = 1 exactly (3116/3125, 237/3125), about 4.35°.
C5, S5 = "0.99712", "0.07584"


def exact_rotation():
    """R = Rz(+4.35°)·Ry(−4.35°) as exact decimal strings (products of 5-digit decimals)."""
    c, s = mpf(C5), mpf(S5)
    ry = mp.matrix([[c, 0, -s], [0, 1, 0], [s, 0, c]])
    rz = mp.matrix([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    r = rz * ry
    # Every entry is a product of at most two 5-digit decimals: 10 decimal places are exact.
    return [[mp.nstr(r[i, j], 30, strip_zeros=True) for j in range(3)] for i in range(3)]


ROTATION = exact_rotation()

LEFT = {"name": "left", "width": 1280, "height": 1024, "fx": "900", "fy": "901.8", "cx": "639.5", "cy": "511.5"}
RIGHT = {"name": "right", "width": 1280, "height": 1024, "fx": "880", "fy": "881.76", "cx": "645.25", "cy": "508.75"}
RIGHT_CENTRE = ["0.12", "0.004", "-0.005"]

RIGS = {
    "single": {
        "normal": ["0.05", "-0.12", "1"], "distance": "0.035", "layers": [],
        "index_air": "1.0", "index_water": "1.333", "distortion": None,
    },
    "glass_distorted": {
        "normal": ["0.3", "0.2", "1"], "distance": "0.045", "layers": [["0.014", "1.473"]],
        "index_air": "1.003", "index_water": "1.333",
        "distortion": ["-0.12", "0.05", "0.0008", "-0.0005", "-0.01"],
    },
    "three_layers": {
        "normal": ["-0.4", "0.25", "1"], "distance": "0.05",
        "layers": [["0.008", "1.52"], ["0.0002", "1.38"], ["0.025", "1.49"]],
        "index_air": "1.0", "index_water": "1.34",
        "distortion": ["0.05", "-0.01", "-0.0003", "0.0004", "0.001"],
    },
    "tank": {
        "normal": ["0.02", "0.03", "1"], "distance": "0.1",
        "layers": [["0.01", "1.5"], ["0.3", "1.333"], ["0.01", "1.5"]],
        "index_air": "1.0", "index_water": "1.0", "distortion": None,
    },
    "immersed": {
        "normal": ["-0.3", "0.1", "1"], "distance": "0.04", "layers": [["0.012", "1.5"]],
        "index_air": "1.333", "index_water": "1.0", "distortion": None,
    },
}


def f(s):
    """The binary64 value of a decimal string, exactly, as an mpf."""
    return mpf(float(s))


def dot(a, b):
    return sum(x * y for x, y in zip(a, b))


def add(a, b):
    return [x + y for x, y in zip(a, b)]


def sub(a, b):
    return [x - y for x, y in zip(a, b)]


def scale(a, k):
    return [x * k for x in a]


def norm(a):
    return mp.sqrt(dot(a, a))


def unit(a):
    return scale(a, 1 / norm(a))


def cross(a, b):
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def matvec(m, v):
    return [dot(row, v) for row in m]


def transpose(m):
    return [[m[j][i] for j in range(3)] for i in range(3)]


def num(x, digits=20):
    return mp.nstr(x, digits, min_fixed=-30, max_fixed=30) if x is not None else "nan"


class Camera:
    def __init__(self, spec, rotation, centre, distortion):
        self.fx, self.fy, self.cx, self.cy = (f(spec[k]) for k in ("fx", "fy", "cx", "cy"))
        self.width, self.height = spec["width"], spec["height"]
        self.rotation = rotation  # cam_from_master
        self.centre = centre
        self.k = [f(x) for x in distortion] if distortion else [mpf(0)] * 5
        self.fold = fold_radius2(self.k)


def fold_radius2(k):
    """Smallest s = r² > 0 with d/dr[r(1 + k1 r² + k2 r⁴ + k3 r⁶)] = 1 + 3k1 s + 5k2 s² + 7k3 s³ = 0."""
    k1, k2, _, _, k3 = k
    coefficients = [7 * k3, 5 * k2, 3 * k1, mpf(1)]
    while coefficients and coefficients[0] == 0:
        coefficients.pop(0)
    if len(coefficients) <= 1:
        return mp.inf
    roots = mp.polyroots(coefficients, maxsteps=200, extraprec=200)
    real = [mp.re(z) for z in roots if abs(mp.im(z)) < mpf("1e-30") and mp.re(z) > 0]
    return min(real) if real else mp.inf


def distort(k, x, y):
    k1, k2, p1, p2, k3 = k
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
    return (x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x), y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y)


def undistort(k, xd, yd):
    """Newton's method on distort(x, y) = (xd, yd) with the analytic Jacobian, from (xd, yd)."""
    k1, k2, p1, p2, k3 = k
    x, y = xd, yd
    for _ in range(200):
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
        dradial = k1 + 2 * k2 * r2 + 3 * k3 * r2 ** 2
        ex, ey = distort(k, x, y)
        ex, ey = ex - xd, ey - yd
        a = radial + 2 * x * x * dradial + 2 * p1 * y + 6 * p2 * x
        b = 2 * x * y * dradial + 2 * p1 * x + 2 * p2 * y
        d = radial + 2 * y * y * dradial + 6 * p1 * y + 2 * p2 * x
        det = a * d - b * b
        dx, dy = (d * ex - b * ey) / det, (a * ey - b * ex) / det
        x, y = x - dx, y - dy
        if abs(dx) + abs(dy) < mpf("1e-48"):
            break
    return x, y


class Rig:
    def __init__(self, name, spec):
        self.name = name
        self.spec = spec
        self.normal = unit([f(x) for x in spec["normal"]])
        self.d = f(spec["distance"])
        self.thicknesses = [f(t) for t, _ in spec["layers"]]
        self.indices = [f(spec["index_air"])] + [f(mu) for _, mu in spec["layers"]] + [f(spec["index_water"])]
        rotation = [[mpf(x) for x in row] for row in ROTATION]
        centre = [mpf(x) for x in RIGHT_CENTRE]
        # Translation t = −R·C written with 25 digits; the centre is then −Rᵀ·t of what was written.
        self.translation = [mp.nstr(x, 25) for x in scale(matvec(rotation, centre), -1)]
        t = [f(x) for x in self.translation]
        right_centre = scale(matvec(transpose(rotation), t), -1)
        identity = [[mpf(int(i == j)) for j in range(3)] for i in range(3)]
        self.cameras = [
            Camera(LEFT, identity, [mpf(0)] * 3, spec["distortion"]),
            Camera(RIGHT, rotation, right_centre, spec["distortion"]),
        ]

    def air_distance(self, k):
        return self.d - dot(self.normal, self.cameras[k].centre)

    def outer(self, k):
        return self.air_distance(k) + sum(self.thicknesses)

    def json(self):
        cams = []
        for spec, extra in ((LEFT, {}), (RIGHT, {"rotation": ROTATION, "translation": self.translation})):
            cam = dict(spec)
            cam["distortion"] = self.spec["distortion"] or ["0", "0", "0", "0", "0"]
            cam.update(extra)
            cams.append(cam)
        return {
            "cameras": cams,
            "interface": {
                "normal": self.spec["normal"],
                "distance": self.spec["distance"],
                "layers": [{"thickness": t, "index": mu} for t, mu in self.spec["layers"]],
                "index_air": self.spec["index_air"],
                "index_water": self.spec["index_water"],
            },
        }


def snell(direction, n, mu1, mu2):
    """Angle form on the tangential component; None on total internal reflection."""
    cos1 = dot(direction, n)
    if cos1 <= 0:
        return "misses"
    tangential = sub(direction, scale(n, cos1))
    sin1 = norm(tangential)
    sin2 = mu1 / mu2 * sin1
    if sin2 >= 1:
        return "tir"
    cos2 = mp.sqrt(1 - sin2 * sin2)
    if sin1 == 0:
        return list(n)
    return add(scale(n, cos2), scale(tangential, sin2 / sin1))


def trace(rig, k, direction):
    """(origin on the outer interface, direction in the water) or 'tir' / 'misses'."""
    n, centre = rig.normal, rig.cameras[k].centre
    point, d = list(centre), unit(direction)
    plane = rig.air_distance(k)
    planes = [plane]
    for t in rig.thicknesses:
        plane += t
        planes.append(plane)
    for i, plane in enumerate(planes):
        along = dot(d, n)
        if along <= 0:
            return "misses"
        point = add(point, scale(d, (plane - dot(n, sub(point, centre))) / along))
        d = snell(d, n, rig.indices[i], rig.indices[i + 1])
        if isinstance(d, str):
            return d
    return point, d


def air_direction(rig, k, point):
    """Bisection on the angle of incidence; returns (direction, angle) or 'not_in_water'."""
    n, centre = rig.normal, rig.cameras[k].centre
    offset = sub(point, centre)
    z = dot(n, offset)
    if z - rig.outer(k) <= 0:
        return "not_in_water"
    lateral = sub(offset, scale(n, z))
    r = norm(lateral)
    if r == 0:
        return list(n), mpf(0)
    e = scale(lateral, 1 / r)

    def miss(a):
        traced = trace(rig, k, add(scale(n, mp.cos(a)), scale(e, mp.sin(a))))
        if isinstance(traced, str):
            return mp.inf
        q, w = traced
        at_depth = add(q, scale(w, (z - dot(n, sub(q, centre))) / dot(n, w)))
        return dot(e, sub(at_depth, centre)) - r

    lo, hi = mpf(0), mp.pi / 2
    while hi - lo > mpf("1e-47"):
        mid = (lo + hi) / 2
        if miss(mid) < 0:
            lo = mid
        else:
            hi = mid
    a = (lo + hi) / 2
    return add(scale(n, mp.cos(a)), scale(e, mp.sin(a))), a


def pixel(camera, direction):
    p = matvec(camera.rotation, direction)
    if p[2] <= 0:
        return "behind_camera"
    x, y = p[0] / p[2], p[1] / p[2]
    if x * x + y * y >= camera.fold:
        return "outside_lens"
    xd, yd = distort(camera.k, x, y)
    return camera.fx * xd + camera.cx, camera.fy * yd + camera.cy


def traced_vop(rig, k, direction, point, depth):
    """x̌ from the intersection of the air line C + s·v with the object axis O + t·n."""
    n, centre = rig.normal, rig.cameras[k].centre
    across = cross(direction, n)
    s = dot(cross(sub(point, centre), n), across) / dot(across, across)
    t = dot(n, sub(add(centre, scale(direction, s)), point))
    return depth + t


def lateral_basis(n):
    helper = [mpf(1), mpf(0), mpf(0)]
    u = unit(sub(helper, scale(n, dot(n, helper))))
    return u, cross(n, u)


def project_rows(rig):
    rows = []
    u, v = lateral_basis(rig.normal)
    for k, camera in enumerate(rig.cameras):
        points = []
        for depth in ("1e-4", "0.3", "1.5", "4.0"):
            for a, b in (("0", "0"), ("0.02", "-0.01"), ("0.25", "0.1"), ("-0.6", "0.35"), ("0.9", "-0.8")):
                p = add(camera.centre, scale(rig.normal, rig.outer(k) + mpf(depth)))
                points.append(add(p, add(scale(u, mpf(a)), scale(v, mpf(b)))))
        # Not in the water: inside the (first) layer or the air, and behind the camera.
        inside = rig.air_distance(k) + (rig.thicknesses[0] / 2 if rig.thicknesses else mpf("-0.01"))
        points.append(add(camera.centre, add(scale(rig.normal, inside), scale(u, mpf("0.1")))))
        points.append(add(camera.centre, scale(rig.normal, mpf("-0.5"))))
        for p in points:
            p = [f(num(x)) for x in p]  # the point as the CSV gives it
            row = {"rig": rig.name, "camera": k, "x": p[0], "y": p[1], "z": p[2]}
            solved = air_direction(rig, k, p)
            if isinstance(solved, str):
                rows.append({**row, "status": solved})
                continue
            direction, a = solved
            px = pixel(camera, direction)
            depth = dot(rig.normal, sub(p, camera.centre)) - rig.outer(k)
            water = trace(rig, k, direction)[1]
            vop = traced_vop(rig, k, direction, p, depth) if a > 0 else None
            row.update(depth=depth, incidence=a, vop_distance=vop, cos_water=dot(rig.normal, water))
            if isinstance(px, str):
                rows.append({**row, "status": px})
            else:
                rows.append({**row, "status": "ok", "u": px[0], "v": px[1]})
    return rows


def backproject_rows(rig):
    rows = []
    for k, camera in enumerate(rig.cameras):
        for u in ("0", "320.25", "639.5", "1000", "1279"):
            for v in ("0", "255.5", "511.5", "1023"):
                uu, vv = f(u), f(v)
                row = {"rig": rig.name, "camera": k, "u": uu, "v": vv}
                x, y = undistort(camera.k, (uu - camera.cx) / camera.fx, (vv - camera.cy) / camera.fy)
                if x * x + y * y >= camera.fold:
                    rows.append({**row, "status": "outside_lens"})
                    continue
                direction = matvec(transpose(camera.rotation), unit([x, y, mpf(1)]))
                traced = trace(rig, k, direction)
                if isinstance(traced, str):
                    rows.append({**row, "status": traced})
                    continue
                origin, w = traced
                rows.append({**row, "status": "ok", "ox": origin[0], "oy": origin[1], "oz": origin[2],
                             "dx": w[0], "dy": w[1], "dz": w[2]})
    return rows


def vop_rows(rig):
    """x̌ for (depth, incidence): trace from the master camera at angle a in the plane spanned by n
    and a lateral direction, go to the depth, intersect the air line with the object axis. At a = 0
    the two lines coincide; there a = 1e-30 is traced (x̌ is even in a: off by O(a²) = 1e-60)."""
    rows = []
    n = rig.normal
    e, _ = lateral_basis(n)
    for depth in ("1e-4", "0.003", "0.2", "1", "5"):
        for incidence in ("0", "0.05", "0.3", "0.6", "0.9", "1.2", "1.5"):
            x, a = f(depth), f(incidence)
            row = {"rig": rig.name, "depth": x, "incidence": a}
            traced_a = a if a > 0 else mpf("1e-30")
            direction = add(scale(n, mp.cos(traced_a)), scale(e, mp.sin(traced_a)))
            traced = trace(rig, 0, direction)
            if isinstance(traced, str):
                rows.append({**row, "status": traced})
                continue
            q, w = traced
            point = add(q, scale(w, x / dot(n, w)))
            rows.append({**row, "status": "ok", "vop_distance": traced_vop(rig, 0, direction, point, x),
                         "cos_water": dot(n, w)})
    return rows


def write_csv(path, columns, rows):
    with open(path, "w") as out:
        out.write("# generated by scripts/golden.py (50-digit mpmath); do not edit\n")
        out.write(",".join(columns) + "\n")
        for row in rows:
            cells = []
            for c in columns:
                value = row.get(c)
                cells.append(value if isinstance(value, str) else str(value) if isinstance(value, int) else num(value))
            out.write(",".join(cells) + "\n")


def main():
    os.makedirs(OUT, exist_ok=True)
    rigs = [Rig(name, spec) for name, spec in RIGS.items()]
    # One rig per line, in DESIGN.md's rig-file format. Numbers were kept as decimal strings so that
    # they are written exactly as given: unquote them.
    lines = [f"  {json.dumps(r.name)}: {json.dumps(r.json())}" for r in rigs]
    text = re.sub(r'"(-?[0-9][0-9.e+-]*)"', r"\1", "{\n" + ",\n".join(lines) + "\n}")
    with open(os.path.join(OUT, "rigs.json"), "w") as out:
        out.write(text + "\n")
    project, backproject, vop = [], [], []
    for rig in rigs:
        project += project_rows(rig)
        backproject += backproject_rows(rig)
        vop += vop_rows(rig)
    write_csv(os.path.join(OUT, "project.csv"),
              ["rig", "camera", "x", "y", "z", "status", "u", "v", "depth", "incidence", "vop_distance", "cos_water"],
              project)
    write_csv(os.path.join(OUT, "backproject.csv"),
              ["rig", "camera", "u", "v", "status", "ox", "oy", "oz", "dx", "dy", "dz"], backproject)
    write_csv(os.path.join(OUT, "vop.csv"),
              ["rig", "depth", "incidence", "status", "vop_distance", "cos_water"], vop)
    for name, rows in (("project", project), ("backproject", backproject), ("vop", vop)):
        statuses = {}
        for row in rows:
            statuses[row["status"]] = statuses.get(row["status"], 0) + 1
        print(f"{name}.csv: {len(rows)} rows {statuses}")


if __name__ == "__main__":
    main()
