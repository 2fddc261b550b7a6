"""Synthetic KITTI-odometry dataset: a procedural town rendered along car-like routes.

``generate(out)`` writes, for each sequence ``NN`` (default ``00``..``12``, each its own world and route)::

    out/sequences/NN/image_2/000000.png ...   8-bit colour PNGs, (height, width) = (160, 512) by default
    out/sequences/NN/calib.txt                P0..P3 (3x4) and Tr (3x4), KITTI format; P2 = [K | 0]
    out/sequences/NN/times.txt                seconds, 10 Hz, KITTI's ``%e`` style
    out/poses/NN.txt                          12 floats a line: row-major 3x4 [R | t] of T_w_c, metres
    out/lossvo_synthetic.json                 the parameters, written last: present = dataset complete

Conventions are KITTI's: camera axes x right, y down, z forward; the world frame is the first camera frame
(first pose = identity), so world y points down and the ground is the plane y = +1.65 m. Camera attitude
is R = Ry(yaw) @ Rx(pitch) @ Rz(roll). The images are rendered with exactly K = P2[:, :3], so poses and
pixels agree to rendering precision: ORB + the 5-point essential matrix recover the written relative
rotations to a median of ~0.15 degree and the translation directions to ~2-3 degrees
(``tests/test_synthetic.py``), the limit of ORB's whole-pixel keypoints at this resolution.

Default resolution: 160 x 512, KITTI's 376 x 1241 scaled by about 0.42 (K scaled per axis, as resizing
KITTI frames does). At 128 x 416 the ORB check above sits too close to its 0.3 degree bound (up to 0.27);
160 x 512 keeps it below 0.18 for a modest cost. Default frame counts are 100-240 per sequence (training
sequences longer than validation ones), 2,100 frames in all: about 50 s of CPU, so the whole default
dataset renders in about half a minute on 2 cores (one process per sequence), ~230 MB of PNGs.

Routes (``lossvo.data.routes``): sequences 00-10 drive a mix of town, arterial and country roads; 11 and
12, the unseen-motion split, drive stop-and-go traffic and expressways, families no other sequence drives.

The scene: an infinite textured ground plane (asphalt-like multi-scale "dead leaves" patches with paint
marks), buildings (vertical boxes with window, brick or panel facades) in rows along both sides of the
route and in city blocks behind them, poles (vertical cylinders), a sky gradient and distance fog.
Rendering is vectorised numpy over the pixels, with one Python loop over the few dozen visible objects
per frame: a ray per pixel is intersected with each visible surface (nearest first, occluded objects
skipped, depth test), then textures are looked up once per pixel with trilinear mip-mapping via
``cv2.remap`` (texture anti-aliasing; silhouettes are not supersampled by default, see SUPERSAMPLE).
Exposure gain, sun, sky, fog and sensor noise vary a little between sequences.

Command line: ``python -m lossvo.data.synthetic --out DIR [--sequences 00,07] [--frames N]
[--height H --width W] [--seed S]``.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import os
import shutil
import sys
import time
from collections.abc import Iterable, Iterator, Mapping
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from lossvo.atomic import write_text_atomic
from lossvo.console import OneLineParser
from lossvo.data import kitti, routes

# --------------------------------------------------------------------------------------------------
# Parameters
# --------------------------------------------------------------------------------------------------

KITTI_SIZE = (376, 1241)
"""(height, width) in pixels of KITTI odometry colour images."""
KITTI_INTRINSICS = (718.856, 718.856, 607.1928, 185.2157)
"""(fx, fy, cx, cy) in pixels of KITTI's P2 at KITTI_SIZE (sequences 00-02)."""

DEFAULT_HEIGHT = 160
DEFAULT_WIDTH = 512
SEQUENCES = tuple(f"{i:02d}" for i in range(11)) + routes.UNSEEN_SEQUENCES
DEFAULT_FRAMES = {
    "00": 240, "01": 120, "02": 240, "03": 120, "04": 100, "05": 200,
    "06": 150, "07": 120, "08": 240, "09": 150, "10": 120, "11": 150, "12": 150,
}  # fmt: skip
"""Frames per sequence when none are given; sequences not listed get FALLBACK_FRAMES."""
FALLBACK_FRAMES = 150
MIN_FRAMES = 2
MIN_SIZE = 32
MAX_SIZE = 4096

CAMERA_HEIGHT = 1.65
"""Metres from the camera centre down to the ground at frame 0; the ground is the world plane y = +1.65."""
FRAME_RATE = 10.0
MANIFEST = "lossvo_synthetic.json"
VERSION = 2
"""Bumped whenever the rendered content changes, so that ensure_dataset regenerates old datasets."""

SUPERSAMPLE = 1
"""Render at SUPERSAMPLE x the resolution and area-average down (anti-aliases silhouettes too). 2 costs
about 2.5x the time and does not improve the ORB check, so textures are anti-aliased by mip-mapping only."""
TEXELS_PER_M = 40.0
"""Texture density of every surface: one texel is 2.5 cm."""
MIP_TOP = 6
"""Coarsest mip level (a texel of 2**6 * 2.5 cm = 1.6 m); tile sizes are multiples of 2**MIP_TOP."""
MARGIN = 2**MIP_TOP
"""Texels of wrapped content around each tile in the atlas, so bilinear lookups never see a seam."""
NEAR = 0.05
"""Metres: nearest depth a surface is drawn at."""
FAR = 2000.0
"""Metres: the ground is drawn up to this depth, the sky beyond."""
CULL = 400.0
"""Metres: objects wholly deeper than this (or than 3 fog distances) are not drawn (fog hides them)."""

# --------------------------------------------------------------------------------------------------
# Camera and calibration
# --------------------------------------------------------------------------------------------------


def intrinsics(height: int, width: int) -> np.ndarray:
    """KITTI's P2 intrinsics scaled to (height, width) pixels: (3, 3) float64 K.

    Each axis is scaled by its own ratio (as resizing a KITTI frame does), about pixel centres:
    c' = (c + 0.5) * s - 0.5.
    """
    fx, fy, cx, cy = KITTI_INTRINSICS
    sx, sy = width / KITTI_SIZE[1], height / KITTI_SIZE[0]
    return np.array([[fx * sx, 0.0, (cx + 0.5) * sx - 0.5], [0.0, fy * sy, (cy + 0.5) * sy - 0.5], [0, 0, 1]])


def calib_text(K: np.ndarray) -> str:
    """KITTI calib.txt content for intrinsics K (3, 3): P0..P3 = K [I | t_i], Tr, 12 floats each.

    The rendered camera is camera 2, so P2 = [K | 0]; the others sit at KITTI's offsets to its right
    (grey cameras 0 and 1 at 0.06 m and 0.60 m, colour camera 3 at 0.53 m); Tr is KITTI's nominal
    velodyne-to-camera axis swap.
    """
    offsets = {"P0": -0.06, "P1": -0.60, "P2": 0.0, "P3": -0.533}
    lines = []
    for name, tx in offsets.items():
        P = K @ np.hstack([np.eye(3), [[tx], [0.0], [0.0]]])
        lines.append(f"{name}: " + " ".join(f"{v:.12e}" for v in P.ravel()))
    velo_to_cam = np.array([[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, -0.08], [1.0, 0.0, 0.0, -0.27]])
    lines.append("Tr: " + " ".join(f"{v:.12e}" for v in velo_to_cam.ravel()))
    return "\n".join(lines) + "\n"


def times_text(n_frames: int) -> str:
    """KITTI times.txt content: one timestamp in seconds a line, FRAME_RATE Hz, starting at 0."""
    return "".join(f"{k / FRAME_RATE:e}\n" for k in range(n_frames))


# --------------------------------------------------------------------------------------------------
# Textures: periodic tiles and their mip-mapped atlas
# --------------------------------------------------------------------------------------------------


def _fill_wrapped(img: np.ndarray, pts: np.ndarray, colour: tuple[float, ...]) -> None:
    """Fill the convex polygon pts (k, 2) int32 (texel x, y in 1/16 texel) on the periodic tile img,
    once for each whole-tile shift of it that overlaps the tile."""
    h, w = img.shape[:2]
    lo, hi = pts.min(0) >> 4, pts.max(0) >> 4
    for sx in (-w, 0, w):
        for sy in (-h, 0, h):
            if hi[0] + sx >= -1 and lo[0] + sx <= w and hi[1] + sy >= -1 and lo[1] + sy <= h:
                shifted = pts + np.array([sx, sy], np.int32) * 16
                cv2.fillConvexPoly(img, shifted, colour, lineType=cv2.LINE_AA, shift=4)


def _shapes(
    rng: np.random.Generator, count: int, radii: tuple[float, float], size: tuple[int, int]
) -> np.ndarray:
    """count random convex shapes (count, 6, 2) int32 in 1/16 texel, largest first, log-uniform radii.

    Rotated rectangles (aspect 0.2-1) and jittered 3-6-gons (padded by repeating a vertex), centred
    uniformly on a (h, w) tile.
    """
    h, w = size
    r = np.sort(np.exp(rng.uniform(np.log(radii[0]), np.log(radii[1]), count)))[::-1, None]
    aspect = rng.uniform(0.2, 1.0, (count, 1))
    xs = np.broadcast_to(np.array([-1.0, 1, 1, -1, -1, -1]), (count, 6))
    rect = np.stack([xs, aspect * np.array([-1.0, -1, 1, 1, 1, 1])], -1)
    phi = np.sort(rng.uniform(0, 2 * np.pi, (count, 6)), axis=1)
    k = rng.integers(3, 7, (count, 1))
    phi = np.where(np.arange(6) < k, phi, np.take_along_axis(phi, k - 1, 1))
    gon = np.stack([np.cos(phi), np.sin(phi)], -1)
    is_rect = (rng.random(count) < 0.6)[:, None, None]
    corners = np.where(is_rect, rect, gon) * r[..., None]
    angle = rng.uniform(0, np.pi, count)
    c, s = np.cos(angle)[:, None], np.sin(angle)[:, None]
    rotated = np.stack(
        [c * corners[..., 0] - s * corners[..., 1], s * corners[..., 0] + c * corners[..., 1]], -1
    )
    centres = rng.uniform((0, 0), (w, h), (count, 1, 2))
    return np.round((centres + rotated) * 16).astype(np.int32)


def _dead_leaves(
    rng: np.random.Generator, img: np.ndarray, count: int, radii: tuple[float, float], colours: np.ndarray
) -> None:
    """Paint count random shapes (largest first, radii in texels) with colours (count, 3) on the tile img."""
    h, w = img.shape[:2]
    shapes = _shapes(rng, count, radii, (h, w))
    inside = (shapes.min(1) >= 0).all(1) & (shapes[..., 0].max(1) < 16 * w) & (shapes[..., 1].max(1) < 16 * h)
    for pts, colour, whole in zip(shapes, colours.tolist(), inside.tolist(), strict=True):
        if whole:
            cv2.fillConvexPoly(img, pts, colour, lineType=cv2.LINE_AA, shift=4)
        else:
            _fill_wrapped(img, pts, colour)


def _grain(rng: np.random.Generator, img: np.ndarray, std: float) -> np.ndarray:
    """img (h, w, 3) uint8 plus per-texel Gaussian grain of the given std (grey levels)."""
    noisy = img + rng.standard_normal(img.shape[:2], dtype=np.float32)[..., None] * np.float32(std)
    return np.clip(noisy, 0, 255, out=noisy).astype(np.uint8)


def ground_texture(rng: np.random.Generator, size: int = 1024) -> np.ndarray:
    """Asphalt-like periodic tile (size, size, 3) uint8 RGB: multi-scale patches, paint marks, grain."""
    base = rng.uniform(85, 120) * np.array([1.0, rng.uniform(0.97, 1.03), rng.uniform(0.95, 1.05)])
    img = np.empty((size, size, 3), np.uint8)
    img[:] = np.clip(base, 0, 255).astype(np.uint8)
    count = 14000
    colours = base * rng.uniform(0.45, 1.55, (count, 1)) * rng.uniform(0.94, 1.06, (count, 3))
    paint = rng.random(count) < 0.03
    colours[paint] = rng.choice(np.array([[225, 225, 220], [220, 190, 70]]), int(paint.sum()))
    _dead_leaves(rng, img, count, (1.5, 60.0), np.clip(colours, 0, 255))
    return _grain(rng, img, 9.0)


def _windows(rng: np.random.Generator, img: np.ndarray, floors: int, columns: int) -> None:
    """Draw a periodic grid of windows (frame, glass, curtain, sill) on a facade tile img (h, w, 3)."""
    h, w = img.shape[:2]
    fh, cw = h // floors, w // columns
    ww, wh = int(cw * rng.uniform(0.35, 0.6)), int(fh * rng.uniform(0.4, 0.6))
    frame = np.clip(rng.uniform(150, 245) + rng.normal(0, 10, 3), 0, 255)
    for f in range(floors):
        for c in range(columns):
            x0, y0 = c * cw + (cw - ww) // 2, f * fh + (fh - wh) // 2
            glass = np.clip(rng.uniform(20, 110) * np.array([0.8, 0.9, 1.1]) + rng.normal(0, 8, 3), 0, 255)
            cv2.rectangle(img, (x0 - 4, y0 - 4), (x0 + ww + 3, y0 + wh + 3), frame.tolist(), -1)
            cv2.rectangle(img, (x0, y0), (x0 + ww - 1, y0 + wh - 1), glass.tolist(), -1)
            curtain = int(wh * rng.uniform(0.0, 0.6))
            if curtain > 2:
                shade = np.clip(glass + rng.uniform(40, 140), 0, 255).tolist()
                cv2.rectangle(img, (x0, y0), (x0 + ww - 1, y0 + curtain), shade, -1)
            cv2.rectangle(img, (x0 - 6, y0 + wh + 3), (x0 + ww + 5, y0 + wh + 7), (frame * 0.8).tolist(), -1)


def _bricks(img: np.ndarray, mortar: np.ndarray) -> None:
    """Overlay a running-bond brick pattern (bricks 10 x 3 texels, mortar 1 texel) on img (h, w, 3)."""
    h, w = img.shape[:2]
    rows = np.arange(h)
    img[rows % 3 == 0] = mortar
    bond = (np.arange(w)[None, :] + 5 * ((rows[:, None] // 3) % 2)) % 10 == 0
    img[bond] = mortar


def facade_texture(rng: np.random.Generator, size: tuple[int, int] = (768, 1024)) -> np.ndarray:
    """Periodic building facade tile (h, w, 3) uint8 RGB (19.2 x 25.6 m): plaster or bricks, windows.

    Row 0 is the top; the renderer anchors the bottom row at the ground. A quarter of the tiles are walls
    (concrete panels with posters and graffiti) instead of windowed facades.
    """
    h, w = size
    palette = np.array([[200, 190, 170], [170, 90, 70], [150, 150, 150], [215, 210, 200], [120, 100, 80]])
    base = np.clip(
        palette[rng.integers(len(palette))] * rng.uniform(0.8, 1.15) * rng.uniform(0.95, 1.05, 3), 0, 255
    )
    img = np.empty((h, w, 3), np.uint8)
    img[:] = base.astype(np.uint8)
    style = rng.integers(4)
    stains = base * rng.uniform(0.8, 1.2, (1500, 1)) * rng.uniform(0.95, 1.05, (1500, 3))
    _dead_leaves(rng, img, 1500, (2.0, 40.0), np.clip(stains, 0, 255))
    if style == 1:
        _bricks(img, np.clip(base * 0.6 + 60, 0, 255).astype(np.uint8))
    if style == 3:
        for x in range(0, w, w // int(rng.choice([8, 16]))):
            img[:, x : x + 2] = (base * 0.5).astype(np.uint8)
        graffiti = 0.6 * rng.uniform(0, 255, (300, 3)) + 0.4 * base
        _dead_leaves(rng, img, 300, (3.0, 30.0), graffiti)
    else:
        _windows(rng, img, int(rng.choice([5, 6])), int(rng.choice([8, 10, 16])))
    return _grain(rng, img, 6.0)


def pole_texture(rng: np.random.Generator, size: tuple[int, int] = (512, 128)) -> np.ndarray:
    """Periodic pole tile (h, w, 3) uint8 RGB (12.8 m tall, 3.2 m around): painted metal with bands."""
    h, w = size
    grey = rng.uniform(90, 180)
    img = np.empty((h, w, 3), np.uint8)
    img[:] = np.clip(grey * np.array([1.0, 1.0, 1.05]), 0, 255).astype(np.uint8)
    bands = np.array([[230, 230, 225], [40, 40, 40], [200, 170, 40], [150, 60, 50], [70, 90, 120]])
    for _ in range(int(rng.integers(1, 5))):
        y0, height = int(rng.integers(0, h - 40)), int(rng.integers(4, 40))
        cv2.rectangle(img, (0, y0), (w - 1, y0 + height), bands[rng.integers(len(bands))].tolist(), -1)
    _dead_leaves(rng, img, 200, (1.5, 8.0), np.clip(grey * rng.uniform(0.5, 1.5, (200, 3)), 0, 255))
    return _grain(rng, img, 8.0)


@dataclass(frozen=True)
class Atlas:
    """All texture tiles of a world and their mip levels, for cv2.remap.

    image: (H, W, 3) uint8 RGB. Level 0 (the tiles, each with a MARGIN of wrapped texels around it) is
    the block at the origin; level l >= 1 is the same block scaled by 2**-l, at (level_x[l], level_y[l]).
    tiles: (T, 4) int64 per tile: level-0 x, y of its first texel, its width and height (texels).
    """

    image: np.ndarray
    level_x: np.ndarray
    level_y: np.ndarray
    tiles: np.ndarray


def build_atlas(tiles: list[np.ndarray]) -> Atlas:
    """Stack periodic tiles (each (h, w, 3), sides multiples of 2**MIP_TOP) with wrapped margins and mips."""
    width = max(t.shape[1] for t in tiles) + 2 * MARGIN
    ys = np.cumsum([0] + [t.shape[0] + 2 * MARGIN for t in tiles])
    level_x = np.array([0] + [width] * MIP_TOP)
    level_y = np.concatenate([[0, 0], np.cumsum([ys[-1] >> lev for lev in range(1, MIP_TOP)])])
    image = np.zeros((ys[-1], width + width // 2, 3), np.uint8)
    for tile, y in zip(tiles, ys[:-1], strict=True):
        small = tile
        for lev in range(MIP_TOP + 1):
            if lev:
                small = cv2.resize(
                    small, (small.shape[1] // 2, small.shape[0] // 2), interpolation=cv2.INTER_AREA
                )
            m = MARGIN >> lev
            x0, y0 = level_x[lev], level_y[lev] + (y >> lev)
            padded = cv2.copyMakeBorder(small, m, m, m, m, cv2.BORDER_WRAP)
            image[y0 : y0 + padded.shape[0], x0 : x0 + padded.shape[1]] = padded
    table = np.array(
        [[MARGIN, y + MARGIN, t.shape[1], t.shape[0]] for t, y in zip(tiles, ys[:-1], strict=True)]
    )
    return Atlas(image, level_x.astype(np.float32), level_y.astype(np.float32), table)


# --------------------------------------------------------------------------------------------------
# World: buildings and poles placed along the route
# --------------------------------------------------------------------------------------------------

PATH_STEP = 0.5
"""Metres between the samples of the route polyline used to place and clear structures."""
FACADES = 5
"""Facade textures per world."""


@dataclass(frozen=True)
class World:
    """A town around one route. Lengths in metres, world frame (y down, ground at y = CAMERA_HEIGHT).

    walls: vertical rectangles, (M, 6) float64 rows x0, z0, x1, z1 (ground segment), y_top, u_offset;
    wall_tile: (M,) atlas tile index. poles: vertical cylinders, (P, 4) rows x, z, radius, y_top;
    pole_tile: (P,). sun: (3,) unit vector towards the sun. Colours are RGB in [0, 1].
    """

    walls: np.ndarray
    wall_tile: np.ndarray
    poles: np.ndarray
    pole_tile: np.ndarray
    atlas: Atlas
    ground_offset: np.ndarray
    sun: np.ndarray
    sky_horizon: np.ndarray
    sky_zenith: np.ndarray
    fog_distance: float
    gain: float
    noise_std: float


def path_samples(xz: np.ndarray, back: float = 40.0, ahead: float = 160.0) -> tuple[np.ndarray, np.ndarray]:
    """Route (N, 2) (x, z) extended straight back and ahead, resampled every PATH_STEP m.

    Returns the points (S, 2) and the unit vectors (S, 2) to the right of the direction of travel.
    """
    d0 = (xz[1] - xz[0]) / max(np.linalg.norm(xz[1] - xz[0]), 1e-9)
    d1 = (xz[-1] - xz[-2]) / max(np.linalg.norm(xz[-1] - xz[-2]), 1e-9)
    poly = np.vstack([xz[0] - back * d0, xz, xz[-1] + ahead * d1])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(poly, axis=0), axis=1))])
    q = np.arange(0.0, s[-1], PATH_STEP)
    pts = np.stack([np.interp(q, s, poly[:, 0]), np.interp(q, s, poly[:, 1])], -1)
    tangent = np.gradient(pts, axis=0)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-9)
    return pts, np.stack([tangent[:, 1], -tangent[:, 0]], -1)


def _clearance(segments: np.ndarray, path: np.ndarray) -> np.ndarray:
    """Smallest distance (m) from each ground segment (K, 2, 2) to the path points (S, 2): (K,)."""
    a, ab = segments[:, None, 0], (segments[:, 1] - segments[:, 0])[:, None]
    ap = path[None] - a
    t = np.clip((ap * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-12), 0.0, 1.0)
    return np.sqrt(((ap - t[..., None] * ab) ** 2).sum(-1)).min(1)


def _footprints(
    rng: np.random.Generator,
    pts: np.ndarray,
    right: np.ndarray,
    side: float,
    offset: tuple[float, float],
    length: tuple[float, float],
) -> list[np.ndarray]:
    """Building footprints (4, 2) in a row along one side (+1 right, -1 left) of the path samples.

    Front faces follow the path at a lateral offset (m) that drifts within ``offset``, with short gaps and
    occasional wide ones (side streets); each footprint is a rectangle 6-15 m deep, away from the path.
    """
    out: list[np.ndarray] = []
    i = int(rng.integers(0, 20))
    lateral = rng.uniform(*offset)
    while True:
        j = i + int(rng.uniform(*length) / PATH_STEP)
        if j >= len(pts):
            return out
        if rng.random() < 0.2:
            lateral = rng.uniform(*offset)
        d = float(np.clip(lateral + rng.normal(0, 0.5), *offset))
        a, b = pts[i] + side * d * right[i], pts[j] + side * d * right[j]
        front = b - a
        if np.linalg.norm(front) > 3.0:
            n = np.array([front[1], -front[0]]) / np.linalg.norm(front)
            n *= np.sign(n @ (side * right[(i + j) // 2])) or 1.0
            depth = rng.uniform(6, 15)
            out.append(np.array([a, b, b + depth * n, a + depth * n]))
        gap = rng.uniform(6, 16) if rng.random() < 0.25 else rng.uniform(0.3, 2.0)
        i = j + max(1, int(gap / PATH_STEP))


def _block_fill(rng: np.random.Generator, pts: np.ndarray, spacing: float = 20.0) -> np.ndarray:
    """Footprints (K, 4, 2) on a jittered grid of city blocks around the path (up to 80 m from it)."""
    lo, hi = pts.min(0) - 80.0, pts.max(0) + 80.0
    gx, gz = np.meshgrid(np.arange(lo[0], hi[0], spacing), np.arange(lo[1], hi[1], spacing))
    centres = np.stack([gx.ravel(), gz.ravel()], -1) + rng.uniform(-2.0, 2.0, (gx.size, 2))
    half = rng.uniform(4.0, 9.0, (len(centres), 1, 2)) * np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]])
    angle = rng.uniform(-0.15, 0.15, (len(centres), 1))
    c, s = np.cos(angle), np.sin(angle)
    corners = np.stack([c * half[..., 0] - s * half[..., 1], s * half[..., 0] + c * half[..., 1]], -1)
    near = _clearance(np.repeat(centres[:, None], 2, 1), pts) < 80.0
    return (centres[:, None] + corners)[near]


def _buildings(rng: np.random.Generator, pts: np.ndarray, right: np.ndarray, n_tiles: int) -> tuple:
    """Walls (M, 6) and their tiles (M,): street-front rows along both sides of the path (4-12 m from it)
    and city blocks filling the space behind; every wall at least 3 m from the path, blocks 7 m."""
    footprints, tops = [], []
    for side in (-1.0, 1.0):
        row = _footprints(rng, pts, right, side, (4.0, 12.0), (6.0, 25.0))
        footprints += row
        tops += list(CAMERA_HEIGHT - rng.uniform(5.0, 20.0, len(row)))
    blocks = _block_fill(rng, pts)
    fp = np.concatenate([np.array(footprints).reshape(-1, 4, 2), blocks])
    top = np.concatenate([tops, CAMERA_HEIGHT - rng.uniform(8.0, 30.0, len(blocks))])
    clear = np.concatenate([np.full(len(fp) - len(blocks), 3.0), np.full(len(blocks), 7.0)])
    edges = np.stack([fp, np.roll(fp, -1, axis=1)], 2)  # (B, 4, 2, 2)
    keep = _clearance(edges.reshape(-1, 2, 2), pts).reshape(-1, 4).min(1) >= clear
    around = np.cumsum(np.linalg.norm(edges[:, :, 1] - edges[:, :, 0], axis=-1), 1)
    u0 = np.concatenate([np.zeros((len(fp), 1)), around[:, :-1]], 1) + rng.uniform(0, 100, (len(fp), 1))
    tiles = np.repeat(rng.integers(1, n_tiles, len(fp))[:, None], 4, 1)
    walls = np.concatenate([edges.reshape(-1, 4, 4), np.repeat(top[:, None, None], 4, 1), u0[..., None]], -1)
    return walls[keep].reshape(-1, 6), tiles[keep].reshape(-1)


def _poles(rng: np.random.Generator, pts: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Poles (P, 4) rows x, z, radius, y_top: every 8-25 m on both sides, 2.2-3.2 m from the path."""
    rows: list[list[float]] = []
    for side in (-1.0, 1.0):
        i = int(rng.integers(0, 30))
        while i < len(pts):
            c = pts[i] + side * rng.uniform(2.2, 3.2) * right[i]
            rows.append([*c, rng.uniform(0.06, 0.2), CAMERA_HEIGHT - rng.uniform(3.0, 9.0)])
            i += int(rng.uniform(8, 25) / PATH_STEP)
    poles = np.array(rows).reshape(-1, 4)
    centres = np.repeat(poles[:, None, :2], 2, 1)
    keep = _clearance(centres, pts) - poles[:, 2] > 1.8
    return poles[keep]


def build_world(rng: np.random.Generator, poses: np.ndarray) -> World:
    """A town around the route poses (N, 4, 4): textures, buildings, poles, light, fog and sensor."""
    tiles = [ground_texture(rng)] + [facade_texture(rng) for _ in range(FACADES)] + [pole_texture(rng)]
    pts, right = path_samples(poses[:, [0, 2], 3])
    walls, wall_tile = _buildings(rng, pts, right, len(tiles) - 1)
    poles = _poles(rng, pts, right)
    azimuth, elevation = rng.uniform(0, 2 * np.pi), rng.uniform(np.radians(25), np.radians(65))
    sun = np.array(
        [np.cos(elevation) * np.sin(azimuth), -np.sin(elevation), np.cos(elevation) * np.cos(azimuth)]
    )
    horizon = np.clip(np.array([0.82, 0.86, 0.9]) + rng.uniform(-0.06, 0.06, 3), 0, 1)
    zenith = np.clip(np.array([0.35, 0.55, 0.85]) + rng.uniform(-0.08, 0.08, 3), 0, 1)
    return World(
        walls=walls,
        wall_tile=wall_tile,
        poles=poles,
        pole_tile=np.full(len(poles), len(tiles) - 1),
        atlas=build_atlas(tiles),
        ground_offset=rng.uniform(0, 1024, 2),
        sun=sun,
        sky_horizon=horizon,
        sky_zenith=zenith,
        fog_distance=float(rng.uniform(120, 220)),
        gain=float(rng.uniform(0.85, 1.15)),
        noise_std=float(rng.uniform(0.5, 2.0)),
    )


# --------------------------------------------------------------------------------------------------
# Rendering
# --------------------------------------------------------------------------------------------------

AMBIENT, DIFFUSE = 0.55, 0.5
"""Lambert shading: brightness = AMBIENT + DIFFUSE * max(0, n . sun)."""
MIN_POLE_PIXELS = 0.3
"""Poles narrower than this on screen (pixels) are not drawn."""

_RECT_EDGES = np.array([[0, 1], [1, 2], [2, 3], [3, 0]])
_BOX_EDGES = np.array(
    [[i, (i + 1) % 4] for i in range(4)]
    + [[4 + i, 4 + (i + 1) % 4] for i in range(4)]
    + [[i, i + 4] for i in range(4)]
)


@dataclass
class GBuffer:
    """Per-pixel nearest surface, (h, w) arrays: depth (camera z, m; inf: sky), texture coordinates u, v
    (m, before the tile's offsets), cos (|n . d| of the unnormalised ray d, for the mip footprint), shade
    (Lambert brightness) and tile (uint8 atlas tile index).
    """

    depth: np.ndarray
    u: np.ndarray
    v: np.ndarray
    cos: np.ndarray
    shade: np.ndarray
    tile: np.ndarray

    def view(self, window: tuple[slice, slice]) -> GBuffer:
        """The same buffers restricted to a pixel window (views: writes go through)."""
        return GBuffer(*(getattr(self, f)[window] for f in ("depth", "u", "v", "cos", "shade", "tile")))

    def write(self, mask: np.ndarray, **values: np.ndarray | float) -> None:
        """Store values (arrays of the window's shape, or scalars) where mask is true."""
        for name, value in values.items():
            np.copyto(getattr(self, name), value, where=mask, casting="unsafe")


def screen_bounds(
    corners: np.ndarray, edges: np.ndarray, K: np.ndarray, size: tuple[int, int], cull: float
) -> tuple[np.ndarray, np.ndarray]:
    """Pixel windows of convex objects given their corners (M, n, 3) in camera coordinates (m).

    The object is clipped at depth NEAR (corners in front plus edge crossings), projected with K (3, 3)
    and bounded. Returns (M, 4) int rows r0, r1, c0, c1 (half-open, clipped to size = (h, w); empty
    windows mark objects out of view or wholly deeper than cull metres) and (M,) the smallest depth (m)
    of the clipped object.
    """
    a, b = corners[:, edges[:, 0]], corners[:, edges[:, 1]]
    za, zb = a[..., 2], b[..., 2]
    crossing = (za > NEAR) != (zb > NEAR)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(crossing, (NEAR - za) / (zb - za), 0.0)
    pts = np.concatenate([corners, a + s[..., None] * (b - a)], 1)
    ok = np.concatenate([corners[..., 2] > NEAR, crossing], 1)
    z = np.where(ok, np.maximum(pts[..., 2], NEAR), 1.0)
    u, v = K[0, 0] * pts[..., 0] / z + K[0, 2], K[1, 1] * pts[..., 1] / z + K[1, 2]
    lo_u, hi_u = np.where(ok, u, np.inf).min(1), np.where(ok, u, -np.inf).max(1)
    lo_v, hi_v = np.where(ok, v, np.inf).min(1), np.where(ok, v, -np.inf).max(1)
    h, w = size
    bounds = np.stack([np.floor(lo_v) - 1, np.ceil(hi_v) + 2, np.floor(lo_u) - 1, np.ceil(hi_u) + 2], 1)
    bounds = np.clip(bounds, 0, [h, h, w, w]).astype(np.int64)
    zmin = np.where(ok, z, np.inf).min(1)
    bounds[zmin > cull] = 0
    return bounds, zmin


def _lut(values: np.ndarray) -> np.ndarray:
    """A cv2.LUT table (1, 256) float32 mapping uint8 index i to values[i] (0 past the end)."""
    lut = np.zeros((1, 256), np.float32)
    lut[0, : len(values)] = values
    return lut


class Renderer:
    """Renders a world from camera poses: (height, width, 3) uint8 BGR frames with intrinsics K (3, 3).

    Deferred shading: each object writes its nearer hits into a g-buffer (one window of pixels per
    object, nearest objects first, occluded ones skipped); one pass then samples the textures, shades,
    fogs and composites over the sky; a last one area-averages the supersampled frame and adds noise.
    """

    def __init__(self, world: World, K: np.ndarray, height: int, width: int, supersample: int | None = None):
        s = SUPERSAMPLE if supersample is None else supersample
        self.world, self.size, self.s = world, (height, width), s
        self.Ks = np.diag([s, s, 1.0]) @ K
        self.Ks[:2, 2] += 0.5 * (s - 1)  # pixel centres: c' = (c + 0.5) s - 0.5
        self.hs, self.ws = height * s, width * s
        self.ux = ((np.arange(self.ws) - self.Ks[0, 2]) / self.Ks[0, 0]).astype(np.float32)
        self.uy = ((np.arange(self.hs) - self.Ks[1, 2]) / self.Ks[1, 1]).astype(np.float32)
        self.dnorm = np.sqrt(self.ux[None, :] ** 2 + self.uy[:, None] ** 2 + 1.0).astype(np.float32)
        self.texel_scale = np.float32(TEXELS_PER_M / math.sqrt(self.Ks[0, 0] * self.Ks[1, 1]))
        self.cull = min(CULL, 3.0 * world.fog_distance)
        self.tile_luts = self._tile_luts(world)
        self.atlas = cv2.cvtColor(world.atlas.image, cv2.COLOR_RGB2BGR)
        self.noise: np.ndarray | None = None
        self.mip_luts = self._mip_luts(world.atlas)
        self.wall_corners = self._wall_corners(world.walls)
        self.pole_corners = self._pole_corners(world.poles)

    @staticmethod
    def _tile_luts(world: World) -> list[np.ndarray]:
        """Per-tile parameters as cv2.LUT tables indexed by tile: x, y of the tile's first texel, its
        width, height and their inverses, u and v offsets (texels)."""
        x, y, w, h = world.atlas.tiles.T.astype(np.float64)
        du, dv = np.zeros(len(x)), np.full(len(x), -CAMERA_HEIGHT * TEXELS_PER_M)
        du[0], dv[0] = world.ground_offset  # walls and poles: v = world y, tiles end at the ground
        return [_lut(col) for col in (x, y, w, h, 1 / w, 1 / h, du, dv)]

    @staticmethod
    def _mip_luts(atlas: Atlas) -> list[np.ndarray]:
        """Per-mip-level scale 2**-l and atlas offsets x, y as cv2.LUT tables indexed by level."""
        return [_lut(col) for col in (0.5 ** np.arange(MIP_TOP + 1), atlas.level_x, atlas.level_y)]

    @staticmethod
    def _wall_corners(walls: np.ndarray) -> np.ndarray:
        """World corners (M, 4, 3) of the wall rectangles (bottom at the ground)."""
        x0, z0, x1, z1, top = (walls[:, i] for i in range(5))
        g = np.full_like(top, CAMERA_HEIGHT)
        return np.stack(
            [np.stack(c, -1) for c in ((x0, g, z0), (x1, g, z1), (x1, top, z1), (x0, top, z0))], 1
        )

    @staticmethod
    def _pole_corners(poles: np.ndarray) -> np.ndarray:
        """World corners (P, 8, 3) of the square prisms that bound the pole cylinders."""
        x, z, r, top = (poles[:, i] for i in range(4))
        ring = [(-1, -1), (1, -1), (1, 1), (-1, 1)]
        corners = [
            np.stack([x + a * r, y, z + b * r], -1)
            for y in (np.full_like(top, CAMERA_HEIGHT), top)
            for a, b in ring
        ]
        return np.stack(corners, 1)

    def render(self, T_w_c: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Frame (height, width, 3) uint8 BGR seen from pose T_w_c (4, 4); rng draws the sensor noise."""
        R, c = T_w_c[:3, :3], T_w_c[:3, 3]
        d = [
            (R[i, 0] * self.ux[None, :] + R[i, 1] * self.uy[:, None] + R[i, 2]).astype(np.float32)
            for i in range(3)
        ]
        g = self._ground(d, c)
        for m, window in self._visible(g, (self.wall_corners - c) @ R, _RECT_EDGES):
            self._draw_wall(g.view(window), [a[window] for a in d], m, c)
        pole_px = self.Ks[0, 0] * 2 * self.world.poles[:, 2]
        for p, window in self._visible(g, (self.pole_corners - c) @ R, _BOX_EDGES, pole_px / MIN_POLE_PIXELS):
            self._draw_pole(g.view(window), [a[window] for a in d], p, c)
        return self._finish(self._colour(g, d), rng)

    def _visible(
        self, g: GBuffer, corners: np.ndarray, edges: np.ndarray, max_depth: np.ndarray | None = None
    ) -> Iterator[tuple[int, tuple[slice, slice]]]:
        """(index, pixel window) of the objects in view (corners (M, n, 3) in camera coordinates), nearest
        first, skipping those deeper than max_depth (M,) and those wholly behind what g holds by then."""
        bounds, zmin = screen_bounds(corners, edges, self.Ks, (self.hs, self.ws), self.cull)
        seen = (bounds[:, 0] < bounds[:, 1]) & (bounds[:, 2] < bounds[:, 3])
        if max_depth is not None:
            seen &= zmin < max_depth
        index = np.flatnonzero(seen)
        for m in index[np.argsort(zmin[index], kind="stable")]:
            r0, r1, c0, c1 = bounds[m]
            window = (slice(r0, r1), slice(c0, c1))
            if g.depth[window].max() > zmin[m]:
                yield int(m), window

    def _ground(self, d: list[np.ndarray], c: np.ndarray) -> GBuffer:
        """G-buffer holding the ground plane y = CAMERA_HEIGHT (up to FAR) hit by the rays d from c."""
        dx, dy, dz = d
        with np.errstate(divide="ignore"):
            t = np.float32(CAMERA_HEIGHT - c[1]) / dy
        t[(dy <= 0) | (t > FAR)] = np.inf
        tt = np.where(np.isfinite(t), t, np.float32(0))
        u, v = np.float32(c[0]) + tt * dx, np.float32(c[2]) + tt * dz
        shade = np.float32(AMBIENT + DIFFUSE * max(0.0, -self.world.sun[1]))
        return GBuffer(t, u, v, np.abs(dy), np.full_like(t, shade), np.zeros(t.shape, np.uint8))

    def _draw_wall(self, g: GBuffer, d: list[np.ndarray], m: int, c: np.ndarray) -> None:
        """Intersect the rays d (h, w) of a window with wall m and store the nearer hits into g."""
        x0, z0, x1, z1, top, u_off = self.world.walls[m]
        length = math.hypot(x1 - x0, z1 - z0)
        ex, ez = (x1 - x0) / length, (z1 - z0) / length
        num = ex * (c[2] - z0) - ez * (c[0] - x0)  # normal n = (-ez, ex)
        denom = np.float32(ex) * d[2] - np.float32(ez) * d[0]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.float32(-num) / denom
        u = np.float32(ex * (c[0] - x0) + ez * (c[2] - z0)) + t * (
            np.float32(ex) * d[0] + np.float32(ez) * d[2]
        )
        y = np.float32(c[1]) + t * d[1]
        mask = (t > NEAR) & (t < g.depth) & (u >= 0) & (u <= np.float32(length)) & (y >= np.float32(top))
        if mask.any():
            facing = math.copysign(1.0, num)  # the lit side is the one the camera is on
            light = AMBIENT + DIFFUSE * max(0.0, facing * (ex * self.world.sun[2] - ez * self.world.sun[0]))
            g.write(
                mask,
                depth=t,
                u=u + np.float32(u_off),
                v=y,
                cos=np.abs(denom),
                shade=light,
                tile=self.world.wall_tile[m],
            )

    def _draw_pole(self, g: GBuffer, d: list[np.ndarray], p: int, c: np.ndarray) -> None:
        """Intersect the rays d (h, w) of a window with pole p (a vertical cylinder); store nearer hits."""
        px, pz, r, top = self.world.poles[p]
        ox, oz = np.float32(c[0] - px), np.float32(c[2] - pz)
        a = d[0] * d[0] + d[2] * d[2]
        b = ox * d[0] + oz * d[2]
        disc = b * b - a * np.float32(ox * ox + oz * oz - r * r)
        with np.errstate(invalid="ignore", divide="ignore"):
            t = (-b - np.sqrt(disc)) / a
        y = np.float32(c[1]) + t * d[1]
        mask = (disc > 0) & (t > NEAR) & (t < g.depth) & (y >= np.float32(top))
        if mask.any():
            nx, nz = (ox + t * d[0]) / np.float32(r), (oz + t * d[2]) / np.float32(r)
            light = AMBIENT + DIFFUSE * np.maximum(
                0, nx * np.float32(self.world.sun[0]) + nz * np.float32(self.world.sun[2])
            )
            g.write(
                mask,
                depth=t,
                u=np.arctan2(nz, nx) * np.float32(r),
                v=y,
                cos=np.abs(nx * d[0] + nz * d[2]),
                shade=light,
                tile=self.world.pole_tile[p],
            )

    def _texels(self, g: GBuffer) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Level-0 atlas coordinates ax, ay and footprint (texels per pixel), (h, w) float32 each."""
        tx, ty, tw, th, inv_w, inv_h, du, dv = (cv2.LUT(g.tile, lut) for lut in self.tile_luts)
        ax, ay = g.u * np.float32(TEXELS_PER_M) + du, g.v * np.float32(TEXELS_PER_M) + dv
        ax -= np.floor(ax * inv_w) * tw  # wrap into [0, width): cheaper than np.mod
        ay -= np.floor(ay * inv_h) * th
        ax += tx
        ay += ty
        cos = np.maximum(g.cos / self.dnorm, np.float32(1e-3))
        footprint = np.minimum(g.depth, np.float32(FAR)) * self.texel_scale / np.sqrt(cos)
        return ax, ay, footprint

    def _sample(self, g: GBuffer) -> list[np.ndarray]:
        """Trilinear (mip-mapped) texture colours at the g-buffer's texels: B, G, R planes (h, w) float32
        in [0, 255]."""
        ax, ay, footprint = self._texels(g)
        level = cv2.log(np.maximum(footprint, np.float32(1e-6))) * np.float32(1 / math.log(2))
        np.clip(level, 0, MIP_TOP, out=level)
        low = np.minimum(level, MIP_TOP - 1).astype(np.uint8)
        frac = level - low
        coarse, fine = cv2.split(self._remap(ax, ay, low + np.uint8(1))), cv2.split(self._remap(ax, ay, low))
        return [f + (c.astype(np.float32) - f) * frac for c, f in zip(coarse, fine, strict=True)]

    def _remap(self, ax: np.ndarray, ay: np.ndarray, level: np.ndarray) -> np.ndarray:
        """Bilinear atlas lookups (h, w, 3) uint8 BGR at level-0 texels ax, ay and mip levels (h, w) uint8."""
        scale, x0, y0 = (cv2.LUT(level, lut) for lut in self.mip_luts)
        mx = (ax + np.float32(0.5)) * scale + (x0 - np.float32(0.5))
        my = (ay + np.float32(0.5)) * scale + (y0 - np.float32(0.5))
        return cv2.remap(self.atlas, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    def _colour(self, g: GBuffer, d: list[np.ndarray]) -> list[np.ndarray]:
        """Shaded surface colours fogged towards the sky behind: B, G, R planes (hs, ws) float32 in [0, 1].

        The fog colour is the sky's colour in the pixel's direction (a vertical gradient from the horizon
        colour at and below the horizon to the zenith colour), so the sky itself is depth = inf.
        """
        w = self.world
        fog = cv2.exp(np.minimum(g.depth, np.float32(1e5)) * np.float32(-1 / w.fog_distance))
        elevation = cv2.sqrt(np.clip(d[1] / self.dnorm * np.float32(-1 / 0.6), 0, 1))
        haze = 1 - fog
        surface = g.shade * fog * np.float32(1 / 255)
        sky = zip(w.sky_horizon[::-1].tolist(), w.sky_zenith[::-1].tolist(), strict=True)
        return [
            tex * surface + (elevation * np.float32(z - h) + np.float32(h)) * haze
            for tex, (h, z) in zip(self._sample(g), sky, strict=True)
        ]

    def _finish(self, colour: list[np.ndarray], rng: np.random.Generator) -> np.ndarray:
        """Area-average colour planes to (height, width), apply exposure gain and sensor noise: (height,
        width, 3) uint8 BGR.

        The noise is a random crop of a Gaussian noise image twice the frame's size, drawn on first use
        (far cheaper than fresh Gaussian draws per frame, and as random to the eye and to a network).
        """
        h, w = self.size
        if self.noise is None:
            self.noise = rng.standard_normal((3, 2 * h, 2 * w), dtype=np.float32) * np.float32(
                self.world.noise_std
            )
        y, x = rng.integers(0, h), rng.integers(0, w)
        planes = []
        for c, plane in enumerate(colour):
            small = cv2.resize(plane, (w, h), interpolation=cv2.INTER_AREA) if self.s > 1 else plane
            small = small * np.float32(255 * self.world.gain) + self.noise[c, y : y + h, x : x + w]
            planes.append(np.clip(small + np.float32(0.5), 0, 255).astype(np.uint8))
        return cv2.merge(planes)


# --------------------------------------------------------------------------------------------------
# Writing sequences and datasets
# --------------------------------------------------------------------------------------------------


def parse_sequences(text: str, label: str = "sequences") -> tuple[str, ...]:
    """'00,07' -> ('00', '07'): comma-separated two-digit sequence numbers, duplicates dropped."""
    names = [s.strip() for s in text.split(",")]
    if not names or any(len(s) != 2 or not s.isdigit() for s in names):
        raise ValueError(f"{label}: expected two-digit sequence numbers like 00,07, got {text!r}")
    return tuple(dict.fromkeys(names))


def resolve_frames(
    sequences: Iterable[str], frames: int | Mapping[str, int] | None, prefix: str = ""
) -> dict[str, int]:
    """Frames per sequence: DEFAULT_FRAMES (None), one count for all (int) or a mapping; validated.

    prefix is put before the parameter names in error messages ("--" for the command line).
    """
    text = sequences if isinstance(sequences, str) else ",".join(sequences)
    sequences = parse_sequences(text, f"{prefix}sequences")
    if frames is None:
        counts = {s: DEFAULT_FRAMES.get(s, FALLBACK_FRAMES) for s in sequences}
    elif isinstance(frames, Mapping):
        counts = {s: int(frames[s]) for s in sequences}
    else:
        counts = dict.fromkeys(sequences, int(frames))
    for n in counts.values():
        if n < MIN_FRAMES:
            raise ValueError(f"{prefix}frames: must be >= {MIN_FRAMES}, got {n}")
    return counts


def check_size(height: int, width: int, prefix: str = "") -> None:
    """Raise ValueError unless MIN_SIZE <= height, width <= MAX_SIZE pixels (prefix: as resolve_frames)."""
    for name, value in (("height", height), ("width", width)):
        if not MIN_SIZE <= value <= MAX_SIZE:
            raise ValueError(f"{prefix}{name}: must be between {MIN_SIZE} and {MAX_SIZE} pixels, got {value}")


PNG_PARAMS = [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY]
if hasattr(cv2, "IMWRITE_PNG_FILTER"):  # OpenCV >= 4.10: one fixed filter is 1.5x faster than choosing
    PNG_PARAMS += [cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_PAETH]


def _streams(sequence: str, seed: int) -> list[np.random.SeedSequence]:
    """Independent seed streams of one sequence: route, world, sensor noise."""
    return np.random.SeedSequence([seed, int(sequence)]).spawn(3)


def sequence_route(
    sequence: str, n_frames: int, seed: int = 0, spec: routes.RouteSpec = routes.DEFAULT_SPEC
) -> np.ndarray:
    """The camera poses T_w_c (n_frames, 4, 4) float64 that generate() writes for this sequence and seed."""
    rng = np.random.default_rng(_streams(sequence, seed)[0])
    return routes.make_route(rng, n_frames, spec.mix(sequence), spec.families)


def scene(
    sequence: str, n_frames: int, seed: int, spec: routes.RouteSpec = routes.DEFAULT_SPEC
) -> tuple[np.ndarray, World, np.random.Generator]:
    """The seeded route poses (N, 4, 4), world and sensor-noise generator of one sequence."""
    _, world_seq, noise_seq = _streams(sequence, seed)
    poses = sequence_route(sequence, n_frames, seed, spec)
    return poses, build_world(np.random.default_rng(world_seq), poses), np.random.default_rng(noise_seq)


def render_sequence(
    folder: Path, sequence: str, n_frames: int, height: int, width: int, seed: int,
    spec: routes.RouteSpec = routes.DEFAULT_SPEC,
) -> None:  # fmt: skip
    """Render one sequence into folder: folder/NN/{image_2/*.png, calib.txt, times.txt} and folder/NN.txt."""
    poses, world, noise = scene(sequence, n_frames, seed, spec)
    K = intrinsics(height, width)
    (folder / sequence / "image_2").mkdir(parents=True)
    (folder / sequence / "calib.txt").write_text(calib_text(K))
    (folder / sequence / "times.txt").write_text(times_text(n_frames))
    renderer = Renderer(world, K, height, width)
    for k, T in enumerate(poses):
        path = folder / sequence / "image_2" / f"{k:06d}.png"
        if not cv2.imwrite(str(path), renderer.render(T, noise), PNG_PARAMS):
            raise OSError(f"could not write {path}")
    kitti.write_poses(folder / f"{sequence}.txt", poses)


def write_sequence(
    out: Path, sequence: str, n_frames: int, height: int, width: int, seed: int,
    spec: routes.RouteSpec = routes.DEFAULT_SPEC,
) -> float:  # fmt: skip
    """Render one sequence into the dataset root out, atomically; returns the seconds it took.

    Everything is rendered into a temporary folder inside out first (removed on failure); the sequence
    folder and then its poses file are moved into place only once complete.
    """
    start = time.perf_counter()
    tmp = out / f".tmp-{sequence}-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        render_sequence(tmp, sequence, n_frames, height, width, seed, spec)
        (out / "sequences").mkdir(exist_ok=True)
        (out / "poses").mkdir(exist_ok=True)
        shutil.rmtree(out / "sequences" / sequence, ignore_errors=True)
        os.replace(tmp / sequence, out / "sequences" / sequence)
        os.replace(tmp / f"{sequence}.txt", out / "poses" / f"{sequence}.txt")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return time.perf_counter() - start


def _header(height: int, width: int, seed: int, spec: routes.RouteSpec) -> dict:
    """The manifest entries that every sequence of one dataset shares (JSON-normalised, so that they
    compare equal to the ones read back from a manifest)."""
    header = {
        "generator": "lossvo.data.synthetic",
        "version": VERSION,
        "height": height,
        "width": width,
        "seed": seed,
        "routes": spec.manifest(),
    }
    return json.loads(json.dumps(header))


def read_manifest(root: Path) -> dict | None:
    """The parameters a complete dataset under root was generated with, or None (absent or unreadable)."""
    try:
        manifest = json.loads((Path(root) / MANIFEST).read_text())
    except (OSError, ValueError):
        return None
    return manifest if isinstance(manifest, dict) else None


def _sequence_complete(root: Path, sequence: str, n_frames: int) -> bool:
    """Whether root holds sequence with its poses, calib, times and n_frames images."""
    seq = root / "sequences" / sequence
    if not all(
        p.is_file() for p in (root / "poses" / f"{sequence}.txt", seq / "calib.txt", seq / "times.txt")
    ):
        return False
    return sum(1 for _ in (seq / "image_2").glob("*.png")) == n_frames


def _kept_sequences(
    root: Path, manifest: dict | None, header: dict, replaced: Iterable[str]
) -> dict[str, int]:
    """Sequences of an existing compatible dataset (same header) that are complete and not re-rendered."""
    if manifest is None or any(manifest.get(k) != v for k, v in header.items()):
        return {}
    frames = manifest.get("frames", {})
    return {s: n for s, n in frames.items() if s not in replaced and _sequence_complete(root, s, n)}


def _render_all(
    out: Path, counts: dict[str, int], height: int, width: int, seed: int, progress: bool,
    workers: int | None, spec: routes.RouteSpec,
) -> None:  # fmt: skip
    """Render the sequences, in parallel spawned worker processes when there are several and cores to spare
    (so a calling script needs the usual ``if __name__ == "__main__":`` guard)."""
    jobs = [(out, s, n, height, width, seed, spec) for s, n in counts.items()]
    workers = min(len(jobs), workers or os.cpu_count() or 1)
    if multiprocessing.current_process().daemon:  # e.g. inside a pool worker: no children allowed
        workers = 1
    pool = None
    if workers > 1:
        context = multiprocessing.get_context("spawn")  # fork is unsafe in threaded (torch) parents
        pool = ProcessPoolExecutor(workers, mp_context=context, initializer=cv2.setNumThreads, initargs=(1,))
    try:
        results = (
            pool.map(write_sequence, *zip(*jobs, strict=True)) if pool else (write_sequence(*j) for j in jobs)
        )
        for (_, s, n, *_), seconds in zip(jobs, results, strict=True):
            if progress:
                print(
                    f"synthetic: sequence {s}: {n} frames {height}x{width} in {seconds:.1f} s",
                    file=sys.stderr,
                )
    finally:
        if pool:
            pool.shutdown(cancel_futures=True)


def generate(
    out: str | Path,
    sequences: Iterable[str] = SEQUENCES,
    frames: int | Mapping[str, int] | None = None,
    height: int = DEFAULT_HEIGHT,
    width: int = DEFAULT_WIDTH,
    seed: int = 0,
    progress: bool = True,
    workers: int | None = None,
    spec: routes.RouteSpec = routes.DEFAULT_SPEC,
) -> Path:
    """Render the synthetic dataset into out in the KITTI odometry layout; returns out as a Path.

    sequences: two-digit names; frames: None (DEFAULT_FRAMES), one count for all, or a mapping; height,
    width: pixels; seed: the same seed gives byte-identical files; spec: route families and mixes
    (:func:`lossvo.data.routes.route_spec`). Sequences of an earlier dataset in out generated with the
    same size, seed and spec are kept. The manifest is removed first and written last, so
    an interrupted run never looks complete.
    """
    out = Path(out)
    counts = resolve_frames(sequences, frames)
    check_size(height, width)
    out.mkdir(parents=True, exist_ok=True)
    header = _header(height, width, seed, spec)
    kept = _kept_sequences(out, read_manifest(out), header, counts)
    (out / MANIFEST).unlink(missing_ok=True)
    _render_all(out, counts, height, width, seed, progress, workers, spec)
    manifest = {**header, "frames": dict(sorted({**kept, **counts}.items()))}
    write_text_atomic(out / MANIFEST, json.dumps(manifest, indent=2) + "\n")
    return out


def ensure_dataset(
    root: str | Path,
    sequences: Iterable[str] = SEQUENCES,
    frames: int | Mapping[str, int] | None = None,
    height: int = DEFAULT_HEIGHT,
    width: int = DEFAULT_WIDTH,
    seed: int = 0,
    progress: bool = True,
    workers: int | None = None,
    spec: routes.RouteSpec = routes.DEFAULT_SPEC,
) -> Path:
    """Root as a Path, holding the requested synthetic sequences: generated unless already there.

    Nothing is rendered when root's manifest has the same generator version, size, seed and routes and
    lists every requested sequence with the requested frame count, and those sequences' files are present.
    """
    root = Path(root)
    counts = resolve_frames(sequences, frames)
    manifest = read_manifest(root)
    header = _header(height, width, seed, spec)
    if manifest is not None and all(manifest.get(k) == v for k, v in header.items()):
        listed = manifest.get("frames", {})
        if all(listed.get(s) == n and _sequence_complete(root, s, n) for s, n in counts.items()):
            return root
    return generate(root, counts, counts, height, width, seed, progress, workers, spec)


# --------------------------------------------------------------------------------------------------
# Command line
# --------------------------------------------------------------------------------------------------


def _parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="python -m lossvo.data.synthetic", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, required=True, help="dataset root to write (KITTI odometry layout)")
    p.add_argument(
        "--sequences", default=",".join(SEQUENCES), help="comma-separated, e.g. 00,07 (default: 00..12)"
    )
    p.add_argument(
        "--frames", type=int, default=None, help="frames per sequence (default: 100-240 by sequence)"
    )
    p.add_argument("--height", type=int, default=DEFAULT_HEIGHT, help=f"pixels (default: {DEFAULT_HEIGHT})")
    p.add_argument("--width", type=int, default=DEFAULT_WIDTH, help=f"pixels (default: {DEFAULT_WIDTH})")
    p.add_argument("--seed", type=int, default=0, help="same seed, same bytes (default: 0)")
    p.add_argument("--workers", type=int, default=None, help="processes (default: one per core)")
    example = "11=stop_and_go:2+expressway"
    p.add_argument("--mix", action="append", default=[], metavar="NN=FAMILY[:W][+FAMILY[:W]]",
                   help=f"route families of a sequence, e.g. {example} (repeatable)")  # fmt: skip
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    return p


def parse_mix(text: str) -> tuple[str, dict[str, float]]:
    """'11=stop_and_go:2+expressway' -> ('11', {'stop_and_go': 2.0, 'expressway': 1.0}); ValueError."""
    sequence, sep, body = text.partition("=")
    if not sep or not body:
        raise ValueError(f"--mix: expected NN=FAMILY[:WEIGHT][+FAMILY[:WEIGHT]], got {text!r}")
    mix = {}
    for item in body.split("+"):
        name, _, weight = item.partition(":")
        try:
            mix[name.strip()] = float(weight) if weight else 1.0
        except ValueError:
            raise ValueError(f"--mix {text}: the weight of {name!r} is not a number: {weight!r}") from None
    try:
        routes.check_mix(mix)
    except ValueError as err:
        raise ValueError(f"--mix {text}: {err}") from None
    return parse_sequences(sequence, "--mix")[0], mix


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point; returns the exit status (2 and a one-line message for bad values)."""
    parser = _parser()
    args = parser.parse_args(argv)
    try:
        counts = resolve_frames(args.sequences, args.frames, prefix="--")
        check_size(args.height, args.width, prefix="--")
        if args.workers is not None and args.workers < 1:
            raise ValueError(f"--workers: must be >= 1, got {args.workers}")
        spec = routes.route_spec(mixes=dict(parse_mix(m) for m in args.mix))
    except ValueError as err:
        parser.error(str(err))
    start = time.perf_counter()
    out = generate(
        args.out, counts, counts, args.height, args.width, args.seed, not args.quiet, args.workers, spec
    )
    if not args.quiet:
        size = dataset_size(out, counts)
        elapsed = time.perf_counter() - start
        print(f"synthetic: wrote {out} in {elapsed:.1f} s, {size / 1e6:.0f} MB", file=sys.stderr)
    return 0


def dataset_size(root: Path, sequences: Iterable[str]) -> int:
    """Bytes on disk of the given sequences' images, calibration, timestamps and pose files."""
    files = [p for s in sequences for p in (root / "sequences" / s).rglob("*") if p.is_file()]
    files += [root / "poses" / f"{s}.txt" for s in sequences]
    return sum(p.stat().st_size for p in files if p.is_file())


if __name__ == "__main__":
    sys.exit(main())
