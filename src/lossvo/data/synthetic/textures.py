"""Textures: procedural periodic RGB tiles ("dead leaves" patches, windows, bricks, bands, grain) for the
ground, facades and poles, and the mip-mapped atlas that holds them; sizes in texels, TEXELS_PER_M a metre."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

TEXELS_PER_M = 40.0
"""Texture density of every surface: one texel is 2.5 cm."""
MIP_TOP = 6
"""Coarsest mip level (a texel of 2**6 * 2.5 cm = 1.6 m); tile sizes are multiples of 2**MIP_TOP."""
MARGIN = 2**MIP_TOP
"""Texels of wrapped content around each tile in the atlas, so bilinear lookups never see a seam."""


def _fill_wrapped(img: np.ndarray, pts: np.ndarray, colour: tuple[float, ...]) -> None:
    """Fill the convex polygon pts (k, 2) int32 (1/16 texel) on the periodic tile img, wrapped around."""
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
    """count random convex shapes (count, 6, 2) int32 in 1/16 texel on a (h, w) tile, largest first:
    rotated rectangles and 3-6-gons (padded by repeating a vertex), log-uniform radii."""
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
    """Periodic building facade tile (h, w, 3) uint8 RGB (row 0 the top): plaster or bricks with windows,
    or a quarter of the time concrete panels with graffiti."""
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
    """All texture tiles of a world and their mip levels, for cv2.remap: image (H, W, 3) uint8 RGB holds
    level 0 (the tiles with wrapped margins) at the origin and level l scaled by 2**-l at (level_x[l],
    level_y[l]); tiles (T, 4): each tile's level-0 first texel x, y, width and height."""

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
