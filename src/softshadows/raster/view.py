"""Camera and light views: the one place world <-> view <-> pixel transforms live.

A :class:`View` is an orthonormal frame (origin, right, up, forward) plus a window:

* view coordinates: ``x = (p-origin).right``, ``y = (p-origin).up``, ``z = (p-origin).forward``;
  ``z`` is the *depth*: distance along the view axis in world units (docs/design.md), for both
  perspective and orthographic views.
* perspective: the window ``(l, r, b, t)`` bounds ``x/z`` and ``y/z`` (the image plane at z = 1),
  so asymmetric (off-axis) frusta are allowed; orthographic: it bounds ``x`` and ``y`` in world units.
* pixels: ``sx = (x' - l) / (r - l) * width`` and ``sy = (t - y') / (t - b) * height`` with
  ``x' = x/z`` (perspective) or ``x`` (ortho). Row 0 is the top; pixel (i, j) has its center at
  ``(j + 0.5, i + 0.5)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.vectors import cross3

# The packed view-parameter vector ``View.params()`` that every kernel reads (``vp[VP_...]``):
# a vector's components are at its index + 0, 1, 2 (x, y, z), e.g. ``vp[VP_FORWARD + 1]``.
VP_ORIGIN = 0  #: origin (3)
VP_RIGHT = 3  #: right (3), unit
VP_UP = 6  #: up (3), unit
VP_FORWARD = 9  #: forward (3), unit: view depth is the distance along it
VP_L = 12  #: window left (window units: x/z perspective, x orthographic)
VP_R = 13  #: window right
VP_B = 14  #: window bottom
VP_T = 15  #: window top
VP_NEAR = 16  #: near plane (view depth)
VP_FAR = 17  #: far plane (view depth)
VP_W = 18  #: image width in pixels
VP_H = 19  #: image height in pixels
VP_ORTHO = 20  #: 1.0 for an orthographic view, 0.0 for a perspective one
VP_SIZE = 21  #: length of the vector


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    n = np.linalg.norm(v)
    if n == 0:
        raise ValueError("zero-length vector")
    return v / n


@dataclass(frozen=True)
class View:
    origin: np.ndarray
    right: np.ndarray
    up: np.ndarray
    forward: np.ndarray
    window: tuple  # (l, r, b, t)
    near: float
    far: float
    width: int
    height: int
    ortho: bool = False

    # ---- constructors -------------------------------------------------------------------
    @staticmethod
    def frame(origin, forward, up_hint, window, near, far, width, height, ortho=False) -> View:
        """Frame with ``right = forward x up_hint`` and ``up = right x forward`` (OpenGL camera
        convention: the image is not mirrored for a camera looking along ``forward``)."""
        f = _unit(forward)
        r = cross3(f, np.asarray(up_hint, float))
        if np.linalg.norm(r) < 1e-9:  # up_hint parallel to forward: pick any perpendicular
            r = cross3(f, np.array([1.0, 0.0, 0.0]) if abs(f[0]) < 0.9 else np.array([0.0, 0.0, 1.0]))
        r = _unit(r)
        u = cross3(r, f)
        return View(
            np.asarray(origin, float).copy(),
            r,
            u,
            f,
            tuple(float(x) for x in window),
            float(near),
            float(far),
            int(width),
            int(height),
            bool(ortho),
        )

    @staticmethod
    def look_at(eye, target, up, fov_y, width, height, near=1e-3, far=1e6) -> View:
        """Symmetric perspective view; ``fov_y`` in degrees, aspect from width/height."""
        t = np.tan(np.radians(fov_y) / 2.0)
        a = width / height
        return View.frame(
            eye,
            np.asarray(target, float) - np.asarray(eye, float),
            up,
            (-t * a, t * a, -t, t),
            near,
            far,
            width,
            height,
            False,
        )

    @staticmethod
    def from_camera(camera, width, height, near=1e-3, far=1e6) -> View:
        return View.look_at(camera.eye, camera.target, camera.up, camera.fov_y, width, height, near, far)

    def resized(self, width, height) -> View:
        return View(
            self.origin,
            self.right,
            self.up,
            self.forward,
            self.window,
            self.near,
            self.far,
            int(width),
            int(height),
            self.ortho,
        )

    # ---- transforms ----------------------------------------------------------------------
    def rotation(self) -> np.ndarray:
        """3x3 matrix whose rows are right, up, forward (world -> view rotation)."""
        return np.stack([self.right, self.up, self.forward])

    def to_view(self, points) -> np.ndarray:
        p = np.asarray(points, dtype=np.float64) - self.origin
        return p @ self.rotation().T

    def params(self) -> np.ndarray:
        """Flat float64 array for kernels: origin(3) right(3) up(3) forward(3) l r b t near far W H ortho,
        indexed with the ``VP_*`` constants of this module."""
        l, r, b, t = self.window
        return np.concatenate(
            [
                self.origin,
                self.right,
                self.up,
                self.forward,
                [l, r, b, t, self.near, self.far, self.width, self.height, 1.0 if self.ortho else 0.0],
            ]
        )

    def project(self, points) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World points -> (sx, sy, depth): continuous pixel coordinates and view depth."""
        q = self.to_view(points)
        z = q[..., 2]
        if self.ortho:
            x, y = q[..., 0], q[..., 1]
        else:
            with np.errstate(divide="ignore", invalid="ignore"):
                x, y = q[..., 0] / z, q[..., 1] / z
        l, r, b, t = self.window
        return (x - l) / (r - l) * self.width, (t - y) / (t - b) * self.height, z

    def pixel_size_at(self, depth: float) -> float:
        """World size of one pixel (x) at a given depth."""
        l, r, _, _ = self.window
        s = (r - l) / self.width
        return s if self.ortho else s * depth

    def unproject(self, sx, sy, depth) -> np.ndarray:
        """Continuous pixel coordinates and view depth -> world points."""
        l, r, b, t = self.window
        x = l + np.asarray(sx, float) / self.width * (r - l)
        y = t - np.asarray(sy, float) / self.height * (t - b)
        d = np.asarray(depth, float)
        if not self.ortho:
            x, y = x * d, y * d
        return self.origin + x[..., None] * self.right + y[..., None] * self.up + d[..., None] * self.forward


def fit_window(view_frame: View, points, margin: float = 0.0) -> tuple:
    """The tightest window (l, r, b, t) of ``view_frame``'s kind containing ``points`` (in front of it)."""
    q = view_frame.to_view(points)
    if view_frame.ortho:
        x, y = q[:, 0], q[:, 1]
    else:
        z = np.maximum(q[:, 2], 1e-9)
        x, y = q[:, 0] / z, q[:, 1] / z
    l, r, b, t = x.min(), x.max(), y.min(), y.max()
    w, h = r - l, t - b
    return (l - margin * w, r + margin * w, b - margin * h, t + margin * h)


def light_frame(light, toward=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(right, up, forward) for a light. Rect: right = u/|u|, forward = normal, up = forward x right
    (so the map is axis-aligned with the rectangle). Sphere: forward = toward - center."""
    if getattr(light, "shape", None) == "rect":
        f = light.normal
        r = _unit(light.u - np.dot(light.u, f) * f)
        u = cross3(f, r)
        return r, u, f
    d = np.asarray(toward, float) - light.center if toward is not None else np.zeros(3)
    # toward the light's own centre (e.g. a light at the occluders' centre) has no direction: look down
    f = (
        _unit(d)
        if np.linalg.norm(d) > 1e-12 * max(1.0, float(np.abs(light.center).max()))
        else np.array([0.0, -1.0, 0.0])
    )
    a = np.array([0.0, 0.0, 1.0]) if abs(f[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    r = _unit(cross3(a, f))
    u = cross3(f, r)
    return r, u, f


def light_view(
    light,
    points,
    width,
    height,
    ortho: bool = False,
    margin: float = 0.02,
    near_min: float = 1e-3,
    square_pixels: bool = False,
    frame: tuple | None = None,
) -> View:
    """A view from the light's center (rect: along its normal; sphere: toward the points' centroid)
    whose window fits ``points`` (e.g. the scene's bounding-box corners or vertices in front of
    the light). near/far bracket the points' depths. ``frame``: (right, up, forward) to use instead
    (e.g. another view's, so that two maps of a sphere light share one frame)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    r, u, f = frame if frame is not None else light_frame(light, toward=(lo + hi) / 2)
    frame = View(light.center.copy(), r, u, f, (-1, 1, -1, 1), near_min, 1.0, width, height, ortho)
    z = frame.to_view(pts)[:, 2]
    front = pts[z > near_min] if not ortho else pts
    if len(front) == 0:
        front = pts
    zf = frame.to_view(front)[:, 2]
    window = fit_window(frame, front, margin)
    if square_pixels:
        l, rr, b, t = window
        cx, cy = (l + rr) / 2, (b + t) / 2
        half = max((rr - l) / width, (t - b) / height) / 2
        window = (cx - half * width, cx + half * width, cy - half * height, cy + half * height)
    near = max(near_min, float(zf.min()) * 0.98) if not ortho else float(zf.min()) - 1e-3
    far = float(zf.max()) * 1.02 + 1e-6
    return View(light.center.copy(), r, u, f, window, near, far, int(width), int(height), ortho)
