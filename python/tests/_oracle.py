"""An independent oracle in plain numpy: brute-force ray tracing through the layer stack with
Snell's law in vector form, and forward projection by bisection on the angle of incidence. It
shares no code with flatport (none of its closed forms, no Newton iteration): only the conventions
of docs/DESIGN.md (OpenCV frames and distortion, X_k = R_k X_master + t_k, planes n·X = d + Σ t_i).
"""

import numpy as np


class OracleRig:
    """The rig JSON's numbers, as plain arrays."""

    def __init__(self, d):
        face = d["interface"]
        n = np.asarray(face["normal"], dtype=float)
        self.n = n / np.linalg.norm(n)
        self.d = float(face["distance"])
        layers = face.get("layers", [])
        self.thicknesses = [float(layer["thickness"]) for layer in layers]
        self.indices = [float(face.get("index_air", 1.0))] + [float(layer["index"]) for layer in layers] + [float(face.get("index_water", 1.333))]
        self.planes = self.d + np.concatenate([[0.0], np.cumsum(self.thicknesses)])
        self.cameras = []
        for cam in d["cameras"]:
            R = np.asarray(cam.get("rotation", np.eye(3)), dtype=float)
            t = np.asarray(cam.get("translation", [0, 0, 0]), dtype=float)
            k = np.zeros(5)
            given = cam.get("distortion", [])
            k[: len(given)] = given
            self.cameras.append(dict(R=R, t=t, C=-R.T @ t, K=(cam["fx"], cam["fy"], cam["cx"], cam["cy"]), k=k))


def distort(cam, x, y):
    k1, k2, p1, p2, k3 = cam["k"]
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    return (x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x), y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y)


def undistort(cam, xd, yd):
    """Inverts the distortion by Newton's method with a numeric Jacobian (only near the centre of
    ordinary lenses, where it is one-to-one)."""
    x, y = xd.copy(), yd.copy()
    h = 1e-7
    for _ in range(50):
        fx, fy = distort(cam, x, y)
        ex, ey = fx - xd, fy - yd
        ax, ay = distort(cam, x + h, y)
        bx, by = distort(cam, x, y + h)
        j11, j21 = (ax - fx) / h, (ay - fy) / h
        j12, j22 = (bx - fx) / h, (by - fy) / h
        det = j11 * j22 - j12 * j21
        x = x - (j22 * ex - j12 * ey) / det
        y = y - (-j21 * ex + j11 * ey) / det
    return x, y


def refract(d, n, mu1, mu2):
    """Snell in vector form for rows d (N, 3), unit n with n·d > 0."""
    r = mu1 / mu2
    c = d @ n
    s2 = r * r * (1 - c * c)
    return r * d + (np.sqrt(1 - s2) - r * c)[:, None] * n


def trace(rig, origins, dirs):
    """Air rays (master frame) through every interface: (origin on the outer interface, water
    direction)."""
    X, d = origins.copy(), dirs / np.linalg.norm(dirs, axis=1)[:, None]
    n = rig.n
    for i, plane in enumerate(rig.planes):
        s = (plane - X @ n) / (d @ n)
        X = X + s[:, None] * d
        d = refract(d, n, rig.indices[i], rig.indices[i + 1])
    return X, d


def backproject(rig, k, pixels):
    cam = rig.cameras[k]
    fx, fy, cx, cy = cam["K"]
    x, y = undistort(cam, (pixels[:, 0] - cx) / fx, (pixels[:, 1] - cy) / fy)
    d_cam = np.stack([x, y, np.ones_like(x)], axis=1)
    d_master = d_cam @ cam["R"]  # Rᵀ d for every row
    origins = np.repeat(cam["C"][None, :], len(pixels), axis=0)
    X, w = trace(rig, origins, d_master)
    return np.hstack([X, w])


def project(rig, k, points, iterations=200):
    """Pixels of points (N, 3) by bisection on the angle of incidence in the plane of refraction."""
    cam = rig.cameras[k]
    n, C = rig.n, cam["C"]
    rel = points - C
    z = rel @ n
    lateral = rel - z[:, None] * n
    r = np.linalg.norm(lateral, axis=1)
    e = lateral / np.where(r > 0, r, 1)[:, None]
    lo = np.zeros(len(points))
    hi = np.full(len(points), np.pi / 2 - 1e-12)

    def reach(a):
        dirs = np.cos(a)[:, None] * n + np.sin(a)[:, None] * e
        X, w = trace(rig, np.repeat(C[None, :], len(points), axis=0), dirs)
        s = (points @ n - X @ n) / (w @ n)
        return np.einsum("ij,ij->i", X + s[:, None] * w - C, e)

    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        with np.errstate(invalid="ignore"):
            beyond = reach(mid) > r
        hi = np.where(beyond, mid, hi)
        lo = np.where(beyond, lo, mid)
    a = 0.5 * (lo + hi)
    dirs = np.cos(a)[:, None] * n + np.sin(a)[:, None] * e
    d_cam = dirs @ cam["R"].T
    x, y = d_cam[:, 0] / d_cam[:, 2], d_cam[:, 1] / d_cam[:, 2]
    xd, yd = distort(cam, x, y)
    fx, fy, cx, cy = cam["K"]
    return np.stack([fx * xd + cx, fy * yd + cy], axis=1)


def closest_midpoint(ray_a, ray_b):
    """Midpoint of the closest approach of two rays (origin, direction) and their distance."""
    pa, da, pb, db = ray_a[:, :3], ray_a[:, 3:], ray_b[:, :3], ray_b[:, 3:]
    w0 = pa - pb
    a, b, c = (da * da).sum(1), (da * db).sum(1), (db * db).sum(1)
    d, e = (da * w0).sum(1), (db * w0).sum(1)
    den = a * c - b * b
    s = (b * e - c * d) / den
    t = (a * e - b * d) / den
    qa, qb = pa + s[:, None] * da, pb + t[:, None] * db
    return np.hstack([(qa + qb) / 2, np.linalg.norm(qa - qb, axis=1)[:, None]])
