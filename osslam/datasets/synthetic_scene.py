"""The synthetic room: axis-aligned boxes with procedural textures, ray-cast per pixel in numpy.

World frame: metres, ``y`` points down (the floor is at ``y = +1.5``). The camera is
inside the room; every object is a solid box standing inside it. A surface point's
brightness depends only on the face it lies on and its position on that face, so the
same point looks the same from every view.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from osslam.types import CameraIntrinsics


@dataclass(frozen=True)
class Box:
    """An axis-aligned box given by its lowest and highest corner in world metres."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]

    @property
    def corners(self) -> np.ndarray:
        """The eight corners as an (8, 3) array."""
        return np.array([[(self.lo, self.hi)[(n >> k) & 1][k] for k in range(3)] for n in range(8)])

    def contains(self, points: np.ndarray, tol: float = 0.0) -> np.ndarray:
        """Which of the (N, 3) ``points`` lie inside the box grown by ``tol`` (shrunk if negative)."""
        return np.all((points >= np.subtract(self.lo, tol)) & (points <= np.add(self.hi, tol)), axis=1)


#: The room: 6 m wide (x), 3 m high (y), 5 m deep (z); the camera starts near its middle looking at +z.
ROOM = Box((-3.0, -1.5, -2.5), (3.0, 1.5, 2.5))
#: Boxes on the floor and two floor-to-ceiling pillars, between the camera and the far wall.
OBJECTS = (
    Box((-1.3, 0.3, 1.5), (-0.6, 1.5, 2.0)),
    Box((0.6, -0.4, 1.7), (1.2, 1.5, 2.2)),
    Box((-0.2, 0.7, 1.2), (0.5, 1.5, 1.6)),
    Box((1.4, -1.5, 1.9), (1.65, 1.5, 2.15)),
    Box((-2.0, -1.5, 1.9), (-1.75, 1.5, 2.15)),
)

TEXEL = 0.006  # metres per texel
_MARGIN = 8  # texels of padding around every face texture
# The two world axes that span a face perpendicular to axis 0, 1, 2 (texture x, texture y).
_TANGENTS = ((2, 1), (0, 2), (0, 1))
_MIN_Z = 0.05  # corners closer than this to the camera plane disable the screen-space cull


def face_texture(rng: np.random.Generator, size: int) -> np.ndarray:
    """A square uint8 texture rich in corners.

    Multi-scale value noise under random rectangles, discs and small high-contrast
    checker patches, lightly blurred so that nothing is a one-texel spike.
    """
    tex = np.full((size, size), 128.0, np.float32)
    for cells, amplitude in ((4, 40.0), (16, 25.0), (64, 14.0), (256, 8.0)):
        grid = rng.uniform(-1.0, 1.0, (cells, cells)).astype(np.float32)
        tex += amplitude * cv2.resize(grid, (size, size), interpolation=cv2.INTER_CUBIC)
    tex = np.clip(tex, 0, 255).astype(np.uint8)
    n_shapes = max(4, int(900 * (size / 1000) ** 2))
    for _ in range(n_shapes):
        x, y = (int(v) for v in rng.integers(0, size, 2))
        w, h = (int(v) for v in rng.integers(6, 40, 2))
        kind = rng.random()
        if kind < 0.6:
            cv2.rectangle(tex, (x, y), (x + w, y + h), int(rng.integers(0, 256)), -1)
        elif kind < 0.85:
            cv2.circle(tex, (x, y), w // 2, int(rng.integers(0, 256)), -1)
        else:
            cell = int(rng.integers(4, 9))
            checker = (np.indices((4, 4)).sum(axis=0) % 2 * 215 + 20).astype(np.uint8)
            patch = np.kron(checker, np.ones((cell, cell), np.uint8))
            tex[y : y + patch.shape[0], x : x + patch.shape[1]] = patch[: size - y, : size - x]
    return cv2.GaussianBlur(tex, (3, 3), 0.8)


class RoomRenderer:
    """Colour and exact depth images of :data:`ROOM` and :data:`OBJECTS` seen from a camera pose.

    Per-pixel rays are computed once; a frame costs one ray/box intersection pass per
    box (objects only inside their projected screen rectangle) and one texture lookup.
    """

    def __init__(self, intrinsics: CameraIntrinsics, rng: np.random.Generator):
        self.intrinsics = intrinsics
        self.room = ROOM
        self.objects = OBJECTS
        self._corners = [box.corners for box in OBJECTS]
        boxes = (ROOM, *OBJECTS)
        sizes = [int(math.ceil(max(np.subtract(b.hi, b.lo)) / TEXEL)) + 2 * _MARGIN for b in boxes for _ in range(6)]
        offsets, atlas_shape = _pack(sizes)
        self.atlas = np.zeros(atlas_shape, np.uint8)
        for (x, y), size in zip(offsets, sizes):
            self.atlas[y : y + size, x : x + size] = face_texture(rng, size)
        # Per face (6 * box + 2 * axis + side): tangent axes and where its texture starts in the atlas.
        n_faces = len(sizes)
        self._axis = np.repeat(np.arange(3), 2)[np.arange(n_faces) % 6].astype(np.uint8)
        self._base = np.zeros((2, n_faces), np.float32)
        for f in range(n_faces):
            lo = boxes[f // 6].lo
            for j, tangent in enumerate(_TANGENTS[self._axis[f]]):
                self._base[j, f] = offsets[f][j] + _MARGIN - lo[tangent] / TEXEL
        self._colour = (rng.uniform(0.55, 1.0, (n_faces, 3)) * rng.uniform(0.8, 1.05, (n_faces, 1))).astype(np.float32)
        h, w = intrinsics.height, intrinsics.width
        u, v = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
        self._ray_x = (u - np.float32(intrinsics.cx)) / np.float32(intrinsics.fx)  # rays (x, y, 1), camera frame
        self._ray_y = (v - np.float32(intrinsics.cy)) / np.float32(intrinsics.fy)

    def render(self, T_world_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Noise-free (H, W, 3) uint8 RGB and (H, W) float32 depth (metres along the optical axis)."""
        h, w = self.intrinsics.height, self.intrinsics.width
        R = T_world_camera[:3, :3].astype(np.float32)
        o = T_world_camera[:3, 3]
        if not self.room.contains(o[None])[0] or any(b.contains(o[None])[0] for b in self.objects):
            raise ValueError(f"camera position {o} is outside the room or inside an object")
        # world ray directions; elementwise rather than a matrix product, which would wake BLAS threads
        d = np.empty((3, h, w), np.float32)
        for k in range(3):
            np.multiply(self._ray_x, R[k, 0], out=d[k])
            d[k] += self._ray_y * R[k, 1]
            d[k] += R[k, 2]
        inv = 1.0 / np.where(d == 0, np.float32(1e-12), d)
        depth, face = self._exit_room(o, d, inv)
        for b, box in enumerate(self.objects, start=1):
            window = self._screen_window(self._corners[b - 1], T_world_camera)
            if window is not None:
                self._hit_box(b, box, o, d[window], inv[window], depth[window[1:]], face[window[1:]])
        gray = self._texture_lookup(o, d, depth, face)
        rgb = np.empty((h, w, 3), np.float32)
        for c in range(3):
            np.multiply(gray, self._colour[:, c][face], out=rgb[:, :, c])
        rgb = cv2.GaussianBlur(rgb, (3, 3), 0.6)
        return np.clip(rgb, 0, 255).astype(np.uint8), depth

    def _exit_room(self, o: np.ndarray, d: np.ndarray, inv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distance along each ray to the wall it leaves the room through, and that wall's face id."""
        t = f = None
        for k in range(3):
            forward = d[k] > 0
            tk = np.where(forward, np.float32(self.room.hi[k] - o[k]), np.float32(self.room.lo[k] - o[k])) * inv[k]
            fk = forward.view(np.uint8) + np.uint8(2 * k)
            if t is None:
                t, f = tk, fk
            else:
                closer = tk < t
                np.copyto(t, tk, where=closer)
                np.copyto(f, fk, where=closer)
        return t, f

    def _hit_box(self, b: int, box: Box, o: np.ndarray, d: np.ndarray, inv: np.ndarray,
                 t: np.ndarray, face: np.ndarray) -> None:
        """Slab test of one solid box; where it is nearer than ``t``, overwrite ``t`` and ``face`` in place."""
        t_near = t_far = face_near = None
        for k in range(3):
            centre = np.float32(0.5 * (box.lo[k] + box.hi[k]) - o[k])
            half = np.float32(0.5 * (box.hi[k] - box.lo[k]))
            mid = centre * inv[k]
            spread = half * np.abs(inv[k])
            near, far = mid - spread, mid + spread
            fk = (d[k] < 0).view(np.uint8) + np.uint8(6 * b + 2 * k)
            if t_near is None:
                t_near, t_far, face_near = near, far, fk
            else:
                later = near > t_near
                np.copyto(t_near, near, where=later)
                np.copyto(face_near, fk, where=later)
                np.minimum(t_far, far, out=t_far)
        hit = (t_near <= t_far) & (t_near > 0) & (t_near < t)
        np.copyto(t, t_near, where=hit)
        np.copyto(face, face_near, where=hit)

    def _screen_window(self, corners: np.ndarray, T_world_camera: np.ndarray) -> tuple[slice, slice, slice] | None:
        """Index of the image rectangle that can see a box with these corners (None: none of it)."""
        h, w = self.intrinsics.height, self.intrinsics.width
        pc = (corners - T_world_camera[:3, 3]) @ T_world_camera[:3, :3]
        z = pc[:, 2]
        if np.all(z <= _MIN_Z):
            return None
        if np.any(z <= _MIN_Z):
            return slice(None), slice(None), slice(None)
        u = self.intrinsics.fx * pc[:, 0] / z + self.intrinsics.cx
        v = self.intrinsics.fy * pc[:, 1] / z + self.intrinsics.cy
        u0, u1 = max(0, int(np.floor(u.min())) - 1), min(w, int(np.ceil(u.max())) + 2)
        v0, v1 = max(0, int(np.floor(v.min())) - 1), min(h, int(np.ceil(v.max())) + 2)
        if u0 >= u1 or v0 >= v1:
            return None
        return slice(None), slice(v0, v1), slice(u0, u1)

    def _texture_lookup(self, o: np.ndarray, d: np.ndarray, t: np.ndarray, face: np.ndarray) -> np.ndarray:
        """Texture brightness (float32) of the hit points ``o + t * d`` on their faces."""
        axis = self._axis[face]
        p = [np.float32(o[k]) + d[k] * t for k in range(3)]
        map_x = self._base[0][face] + np.where(axis == 0, p[2], p[0]) * np.float32(1 / TEXEL)
        map_y = self._base[1][face] + np.where(axis == 1, p[2], p[1]) * np.float32(1 / TEXEL)
        gray = cv2.remap(self.atlas, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        return gray.astype(np.float32)


def _pack(sizes: list[int]) -> tuple[list[tuple[int, int]], tuple[int, int]]:
    """Shelf-pack squares of the given sizes into an atlas; their (x, y) offsets and the atlas (rows, cols)."""
    width = max(sizes) * 6
    x = y = row = 0
    offsets = []
    for s in sizes:
        if x + s > width:
            x, y, row = 0, y + row, 0
        offsets.append((x, y))
        x, row = x + s, max(row, s)
    return offsets, (y + row, width)
