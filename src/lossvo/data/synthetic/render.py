"""Rendering by ray casting with deferred shading: each visible wall and pole (nearest first) writes its
hits into a g-buffer over the ground's; textures are sampled once per pixel (trilinear mip-mapping,
``cv2.remap``), shaded (Lambert), fogged towards the sky and given sensor noise. A distorted camera is
rendered along each pixel's undistorted ray (:func:`undistorted_rays`, :class:`RayGrid`)."""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import cv2
import numpy as np

from lossvo.console import UserError
from lossvo.data.synthetic.camera import CAMERA_HEIGHT
from lossvo.data.synthetic.textures import MIP_TOP, TEXELS_PER_M
from lossvo.data.synthetic.world import World

NEAR = 0.05
"""Metres: nearest depth a surface is drawn at."""
FAR = 2000.0
"""Metres: the ground is drawn up to this depth, the sky beyond."""
CULL = 400.0
"""Metres: objects wholly deeper than this (or than 3 fog distances) are not drawn (fog hides them)."""
AMBIENT, DIFFUSE = 0.55, 0.5
"""Lambert shading: brightness = AMBIENT + DIFFUSE * max(0, n . sun)."""
MIN_POLE_PIXELS = 0.3
"""Poles narrower than this on screen (pixels) are not drawn."""

_RECT_EDGES = np.array([[0, 1], [1, 2], [2, 3], [3, 0]])
_BOX_EDGES = np.concatenate([_RECT_EDGES, _RECT_EDGES + 4, [[i, i + 4] for i in range(4)]])


@dataclass
class GBuffer:
    """Per-pixel nearest surface, (h, w) arrays: depth (camera z, m; inf: sky), texture coordinates u, v
    (m), cos (|n . d| of the unnormalised ray d, for the mip footprint), shade and tile (uint8 index)."""

    depth: np.ndarray
    u: np.ndarray
    v: np.ndarray
    cos: np.ndarray
    shade: np.ndarray
    tile: np.ndarray

    def view(self, window: tuple[slice, slice]) -> GBuffer:
        """The same buffers restricted to a pixel window (views: writes go through)."""
        return GBuffer(*(buffer[window] for buffer in vars(self).values()))

    def write(self, mask: np.ndarray, *values: np.ndarray | float) -> None:
        """Store a value (an array of the window's shape, or a scalar) in every buffer, in field order, where
        mask is true."""
        for buffer, value in zip(vars(self).values(), values, strict=True):
            np.copyto(buffer, value, where=mask, casting="unsafe")


UNDISTORT_ITERATIONS = 200
"""Fixed-point iterations at most when undistorting the pixel grid (stops once converged)."""
UNDISTORT_TOLERANCE = 1e-10
"""Largest residual (normalised image units) of an undistorted ray re-distorted onto its pixel."""


def _lens_terms(
    x: np.ndarray, y: np.ndarray, distortion: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """OpenCV's radial-tangential model at normalised (x, y): the radial factor and the tangential offsets
    (dx, dy), distorted = (x radial + dx, y radial + dy)."""
    k1, k2, p1, p2, k3 = np.concatenate([np.asarray(distortion, np.float64), np.zeros(5)])[:5]
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    return radial, 2 * p1 * x * y + p2 * (r2 + 2 * x * x), p1 * (r2 + 2 * y * y) + 2 * p2 * x * y


def undistorted_rays(
    K: np.ndarray, distortion: np.ndarray, size: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """Undistorted normalised coordinates (x/z, y/z), (h, w) float64 each, of every pixel centre of a
    size = (h, w) frame seen through K and distortion (k1, k2, p1, p2[, k3]): OpenCV's fixed-point
    iteration until converged; UserError where it does not (a lens model that folds)."""
    h, w = size
    xd = np.broadcast_to((np.arange(w) - K[0, 2]) / K[0, 0], (h, w))
    yd = np.broadcast_to((np.arange(h)[:, None] - K[1, 2]) / K[1, 1], (h, w))
    x, y = xd.copy(), yd.copy()
    for _ in range(UNDISTORT_ITERATIONS):
        radial, dx, dy = _lens_terms(x, y, distortion)
        if max(np.abs(x * radial + dx - xd).max(), np.abs(y * radial + dy - yd).max()) < UNDISTORT_TOLERANCE:
            return x, y
        x, y = (xd - dx) / radial, (yd - dy) / radial
    raise UserError(f"distortion {list(distortion)}: the pixel grid does not undistort (no convergence)")


@dataclass
class RayGrid:
    """Per-pixel rays of a distorted camera, ux, uy (h, w) float32 undistorted normalised coordinates, and
    their monotone envelopes (col_max[c]: max of ux over columns <= c, col_min[c]: min over columns >= c;
    rows likewise), which bound the pixels whose rays may fall in a rectangle."""

    ux: np.ndarray
    uy: np.ndarray

    def __post_init__(self) -> None:
        self.col_max = np.maximum.accumulate(self.ux.max(0).astype(np.float64))
        self.col_min = np.minimum.accumulate(self.ux.min(0).astype(np.float64)[::-1])[::-1]
        self.row_max = np.maximum.accumulate(self.uy.max(1).astype(np.float64))
        self.row_min = np.minimum.accumulate(self.uy.min(1).astype(np.float64)[::-1])[::-1]

    def windows(self, x0: np.ndarray, x1: np.ndarray, y0: np.ndarray, y1: np.ndarray) -> np.ndarray:
        """(M, 4) int rows r0, r1, c0, c1 (half-open, one pixel of margin) of the pixels whose rays may
        fall in the rectangles [x0, x1] x [y0, y1] (M,) of normalised coordinates."""
        h, w = self.ux.shape
        c0 = np.searchsorted(self.col_max, x0, side="left") - 1
        c1 = np.searchsorted(self.col_min, x1, side="right") + 1
        r0 = np.searchsorted(self.row_max, y0, side="left") - 1
        r1 = np.searchsorted(self.row_min, y1, side="right") + 1
        return np.clip(np.stack([r0, r1, c0, c1], 1), 0, [h, h, w, w]).astype(np.int64)


def screen_bounds(
    corners: np.ndarray,
    edges: np.ndarray,
    K: np.ndarray,
    size: tuple[int, int],
    cull: float,
    grid: RayGrid | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Pixel windows (M, 4) int rows r0, r1, c0, c1 (half-open; empty: out of view or deeper than cull m)
    and nearest depths (M,) m of convex objects with corners (M, n, 3) in camera coordinates, clipped at
    NEAR and projected with K (through grid's rays when given)."""
    a, b = corners[:, edges[:, 0]], corners[:, edges[:, 1]]
    za, zb = a[..., 2], b[..., 2]
    crossing = (za > NEAR) != (zb > NEAR)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(crossing, (NEAR - za) / (zb - za), 0.0)
    pts = np.concatenate([corners, a + s[..., None] * (b - a)], 1)
    ok = np.concatenate([corners[..., 2] > NEAR, crossing], 1)
    z = np.where(ok, np.maximum(pts[..., 2], NEAR), 1.0)
    if grid is None:
        u, v = K[0, 0] * pts[..., 0] / z + K[0, 2], K[1, 1] * pts[..., 1] / z + K[1, 2]
    else:
        u, v = pts[..., 0] / z, pts[..., 1] / z
    lo_u, hi_u = np.where(ok, u, np.inf).min(1), np.where(ok, u, -np.inf).max(1)
    lo_v, hi_v = np.where(ok, v, np.inf).min(1), np.where(ok, v, -np.inf).max(1)
    h, w = size
    if grid is None:
        bounds = np.stack([np.floor(lo_v) - 1, np.ceil(hi_v) + 2, np.floor(lo_u) - 1, np.ceil(hi_u) + 2], 1)
        bounds = np.clip(bounds, 0, [h, h, w, w]).astype(np.int64)
    else:
        bounds = grid.windows(lo_u, hi_u, lo_v, hi_v)
    zmin = np.where(ok, z, np.inf).min(1)
    bounds[zmin > cull] = 0
    return bounds, zmin


def _lut(values: np.ndarray) -> np.ndarray:
    """A cv2.LUT table (1, 256) float32 mapping uint8 index i to values[i] (0 past the end)."""
    lut = np.zeros((1, 256), np.float32)
    lut[0, : len(values)] = values
    return lut


def _tile_luts(world: World) -> list[np.ndarray]:
    """Per-tile cv2.LUT tables: first texel x, y, width, height, their inverses, u and v offsets."""
    x, y, w, h = world.atlas.tiles.T.astype(np.float64)
    du, dv = np.zeros(len(x)), np.full(len(x), -CAMERA_HEIGHT * TEXELS_PER_M)
    du[0], dv[0] = world.ground_offset  # walls and poles: v = world y, tiles end at the ground
    return [_lut(col) for col in (x, y, w, h, 1 / w, 1 / h, du, dv)]


def _wall_corners(walls: np.ndarray) -> np.ndarray:
    """World corners (M, 4, 3) of the wall rectangles (bottom at the ground)."""
    x0, z0, x1, z1, top = (walls[:, i] for i in range(5))
    g = np.full_like(top, CAMERA_HEIGHT)
    return np.stack([np.stack(c, -1) for c in ((x0, g, z0), (x1, g, z1), (x1, top, z1), (x0, top, z0))], 1)


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


class Renderer:
    """Renders a world from camera poses: (height, width, 3) uint8 BGR frames with intrinsics K (3, 3) and,
    when given and not all zero, lens distortion (k1, k2, p1, p2[, k3]) (frames rendered distorted)."""

    def __init__(
        self,
        world: World,
        K: np.ndarray,
        height: int,
        width: int,
        distortion: np.ndarray | None = None,
    ):
        self.world, self.size, self.K = world, (height, width), np.array(K, np.float64)
        self.grid: RayGrid | None = None
        if distortion is not None and np.any(np.asarray(distortion) != 0):
            ux, uy = undistorted_rays(self.K, np.asarray(distortion, np.float64), self.size)
            self.grid = RayGrid(ux.astype(np.float32), uy.astype(np.float32))
            self.ux, self.uy = self.grid.ux, self.grid.uy
        else:  # (1, w) and (h, 1): broadcast over the frame
            self.ux = ((np.arange(width) - self.K[0, 2]) / self.K[0, 0]).astype(np.float32)[None, :]
            self.uy = ((np.arange(height) - self.K[1, 2]) / self.K[1, 1]).astype(np.float32)[:, None]
        self.dnorm = np.sqrt(self.ux**2 + self.uy**2 + 1.0).astype(np.float32)
        self.texel_scale = np.float32(TEXELS_PER_M / math.sqrt(self.K[0, 0] * self.K[1, 1]))
        self.cull = min(CULL, 3.0 * world.fog_distance)
        self.tile_luts = _tile_luts(world)
        self.atlas = cv2.cvtColor(world.atlas.image, cv2.COLOR_RGB2BGR)
        self.noise: np.ndarray | None = None
        levels = (0.5 ** np.arange(MIP_TOP + 1), world.atlas.level_x, world.atlas.level_y)
        self.mip_luts = [_lut(col) for col in levels]  # scale 2**-l and atlas offsets x, y by mip level
        self.wall_corners = _wall_corners(world.walls)
        self.pole_corners = _pole_corners(world.poles)

    def render(self, T_w_c: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Frame (height, width, 3) uint8 BGR seen from pose T_w_c (4, 4); rng draws the sensor noise."""
        R, c = T_w_c[:3, :3], T_w_c[:3, 3]
        d = [(R[i, 0] * self.ux + R[i, 1] * self.uy + R[i, 2]).astype(np.float32) for i in range(3)]
        g = self._ground(d, c)
        for m, window in self._visible(g, (self.wall_corners - c) @ R, _RECT_EDGES):
            self._draw_wall(g.view(window), [a[window] for a in d], m, c)
        pole_px = self.K[0, 0] * 2 * self.world.poles[:, 2]
        for p, window in self._visible(g, (self.pole_corners - c) @ R, _BOX_EDGES, pole_px / MIN_POLE_PIXELS):
            self._draw_pole(g.view(window), [a[window] for a in d], p, c)
        return self._finish(self._colour(g, d), rng)

    def _visible(
        self, g: GBuffer, corners: np.ndarray, edges: np.ndarray, max_depth: np.ndarray | None = None
    ) -> Iterator[tuple[int, tuple[slice, slice]]]:
        """(index, pixel window) of the objects in view (corners (M, n, 3) in camera coordinates), nearest
        first, skipping those deeper than max_depth (M,) and those wholly behind what g holds by then."""
        bounds, zmin = screen_bounds(corners, edges, self.K, self.size, self.cull, self.grid)
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
            g.write(mask, t, u + np.float32(u_off), y, np.abs(denom), light, self.world.wall_tile[m])

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
            u = np.arctan2(nz, nx) * np.float32(r)
            g.write(mask, t, u, y, np.abs(nx * d[0] + nz * d[2]), light, self.world.pole_tile[p])

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
        """Shaded surface colours fogged towards the sky's colour in the pixel's direction (a gradient from
        horizon to zenith; the sky itself is depth = inf): B, G, R planes (h, w) float32 in [0, 1]."""
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
        """Colour planes with exposure gain and sensor noise, (height, width, 3) uint8 BGR; the noise is a
        random crop of a Gaussian noise image twice the frame's size (cheaper than fresh draws)."""
        h, w = self.size
        if self.noise is None:
            self.noise = rng.standard_normal((3, 2 * h, 2 * w), dtype=np.float32) * np.float32(
                self.world.noise_std
            )
        y, x = rng.integers(0, h), rng.integers(0, w)
        planes = []
        for c, plane in enumerate(colour):
            value = plane * np.float32(255 * self.world.gain) + self.noise[c, y : y + h, x : x + w]
            planes.append(np.clip(value + np.float32(0.5), 0, 255).astype(np.uint8))
        return cv2.merge(planes)
