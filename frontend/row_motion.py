"""The camera's motion over a rolling-shutter frame: a rigid motion that changes from row to row.

A rolling-shutter camera (Kinect, Xtion) exposes its rows one after the other, so when the
camera's motion changes within a frame, the rows see different motions between two frames:
the flow of the bottom rows departs from that of the middle rows, which no single rigid
motion explains. Here the motion of a point seen on a row is the middle row's motion applied
after a small motion proportional to the row's offset from the middle, in image heights.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from osslam.geometry import project_pinhole, row_lengths, transform_points

ITERATIONS = 4
WARM_ITERATIONS = 2  # from a row motion already fitted to nearly the same points
MIN_POINTS = 125  # the fit's 12 parameters need points spread over the rows
HUBER_PX = 1.0  # residuals beyond this many pixels count linearly (movers among the points)
DAMPING = 1e-3  # Levenberg-Marquardt damping, relative to the normal matrix's diagonal


@dataclass(frozen=True)
class RowMotion:
    """T_previous_current of the image's middle row and its change per image height.

    ``change`` holds a rotation vector and a translation (metres) added to the motion of a
    row one image height below the middle; None means the same motion for every row.
    """

    T: np.ndarray  # 4x4
    change: np.ndarray | None = None  # (6,): rotation (3), translation (3)
    height: int = 1

    def offsets(self, rows: np.ndarray) -> np.ndarray:
        """Each of image ``rows``' offset from the middle row, in image heights (-0.5 at the top)."""
        return (rows - self.height / 2.0) / self.height

    def apply(self, X: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Points ``X`` (N, 3) of the current camera, seen on image ``rows`` (N,), in the previous camera."""
        turned, offset = self._parts(X, rows)
        return turned + offset

    def apply_along_rays(self, X: np.ndarray, rows: np.ndarray, scale: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`apply` to points ``X`` and to the same points scaled by ``scale`` (N,) along their rays."""
        turned, offset = self._parts(X, rows)
        return turned + offset, turned * scale[:, None] + offset

    def _parts(self, X: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The motion of points ``X`` as a part linear in them and an offset, whose sum :meth:`apply` gives."""
        R, t = self.T[:3, :3], self.T[:3, 3]
        if self.change is None:
            return X @ R.T, t
        s = self.offsets(rows)[:, None]
        return (X + s * (X @ _skew(self.change[:3]).T)) @ R.T, (s * self.change[3:]) @ R.T + t


def _skew(w: np.ndarray) -> np.ndarray:
    """The matrix of the cross product with ``w``: ``_skew(w) @ x`` is w x x."""
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def _jacobian(motion: RowMotion, X: np.ndarray, rows: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Projections (N, 2) of the points under ``motion`` and their derivatives (2N, 12), u rows before v rows.

    Parameters: a rotation and a translation applied after the middle row's motion, then the
    change's rotation and translation.
    """
    offsets = motion.offsets(rows)[:, None]
    P = motion.apply(X, rows)
    R = motion.T[:3, :3]
    inv_z = 1.0 / np.maximum(P[:, 2], 1e-6)
    n = len(P)
    J = np.zeros((2 * n, 12))
    # derivatives of u and v by the point after the motion: (fx / z, 0, -fx x / z^2) and (0, fy / z, -fy y / z^2)
    J[:n, 3] = K[0, 0] * inv_z
    J[:n, 5] = -K[0, 0] * P[:, 0] * inv_z**2
    J[n:, 4] = K[1, 1] * inv_z
    J[n:, 5] = -K[1, 1] * P[:, 1] * inv_z**2
    both = np.concatenate([P, P])
    J[:, 0:3] = _cross(both, J[:, 3:6])  # a rotation after the motion moves the point by (rotation x P)
    back = J[:, 3:6] @ R  # the same derivatives with respect to the point before the middle row's motion
    twice = np.concatenate([offsets, offsets])
    J[:, 6:9] = twice * _cross(np.concatenate([X, X]), back)
    J[:, 9:12] = twice * back
    return project_pinhole(P, K), J


def _cross(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Row-wise cross products of (N, 3) arrays, as ``np.cross`` gives them but faster on small arrays."""
    out = np.empty(A.shape)
    out[:, 0] = A[:, 1] * B[:, 2] - A[:, 2] * B[:, 1]
    out[:, 1] = A[:, 2] * B[:, 0] - A[:, 0] * B[:, 2]
    out[:, 2] = A[:, 0] * B[:, 1] - A[:, 1] * B[:, 0]
    return out


def fit_row_motion(start: np.ndarray | RowMotion, X: np.ndarray, uv: np.ndarray, rows: np.ndarray, height: int,
                   K: np.ndarray) -> RowMotion | None:
    """The row motion taking points ``X`` (seen on ``rows``) onto pixels ``uv``, from a rigid motion or a row motion.

    Gauss-Newton with Huber weights, damped, for ``ITERATIONS`` steps from a rigid ``start``
    (4x4) and ``WARM_ITERATIONS`` from a row motion; None for fewer than ``MIN_POINTS``
    points or when it does not lower the points' median reprojection error below that of
    the start's middle-row motion alone.
    """
    if len(X) < MIN_POINTS:
        return None
    warm = isinstance(start, RowMotion) and start.change is not None
    T = start.T if isinstance(start, RowMotion) else start
    motion = RowMotion(T, start.change if warm else np.zeros(6), height)
    before = None  # the start's median reprojection error, its rigid motion alone
    for _ in range(WARM_ITERATIONS if warm else ITERATIONS):
        proj, J = _jacobian(motion, X, rows, K)
        r = proj - uv
        e = row_lengths(r)
        if before is None and not warm:  # a cold start's first projections are those of its rigid motion
            before = np.median(e)
        w = np.where(e <= HUBER_PX, 1.0, HUBER_PX / np.maximum(e, 1e-12))
        Jw = J * np.concatenate([w, w])[:, None]
        H = Jw.T @ J
        H[np.diag_indices(12)] *= 1.0 + DAMPING
        H[np.diag_indices(12)] += 1e-9
        step = np.linalg.solve(H, -(Jw.T @ r.T.ravel()))
        update = np.eye(4)
        update[:3, :3] = cv2.Rodrigues(step[:3])[0]
        update[:3, 3] = step[3:6]
        motion = RowMotion(update @ motion.T, motion.change + step[6:], height)
    if before is None:
        before = np.median(row_lengths(project_pinhole(transform_points(T, X), K) - uv))
    after = np.median(row_lengths(project_pinhole(motion.apply(X, rows), K) - uv))
    return motion if after < before else None
