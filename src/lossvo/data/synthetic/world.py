"""The world of a sequence: a town around its route (a textured ground plane, buildings in rows along the
route and in blocks behind, poles, sky and fog), and each sequence's seeded route, world and sensor-noise
streams. Metres in the first camera frame (x right, y down, z forward; the ground is y = CAMERA_HEIGHT)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lossvo.data.synthetic import routes
from lossvo.data.synthetic.camera import CAMERA_HEIGHT
from lossvo.data.synthetic.textures import Atlas, build_atlas, facade_texture, ground_texture, pole_texture

PATH_STEP = 0.5
"""Metres between the samples of the route polyline used to place and clear structures."""
FACADES = 5
"""Facade textures per world."""


@dataclass(frozen=True)
class World:
    """A town around one route: walls (M, 6) rows x0, z0, x1, z1 (ground segment), y_top, u_offset; poles
    (P, 4) rows x, z, radius, y_top; their atlas tiles (M,), (P,); sun (3,) a unit vector towards the sun;
    sky colours RGB in [0, 1]."""

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
    """Points (S, 2) of a route (N, 2) (x, z) extended straight back and ahead, every PATH_STEP m, and
    the unit vectors (S, 2) to their right."""
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
    """Building footprints (4, 2) in a row along one side (+1 right, -1 left) of the path, fronts at a
    lateral offset (m) drifting within ``offset``, with gaps (side streets), 6-15 m deep."""
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
    """Walls (M, 6) and their tiles (M,): rows along both sides of the path (4-12 m from it) and blocks
    behind; every wall at least 3 m from the path, blocks 7 m."""
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


def _streams(sequence: str, seed: int) -> list[np.random.SeedSequence]:
    """Independent seed streams of one sequence: route, world, sensor noise."""
    return np.random.SeedSequence([seed, int(sequence)]).spawn(3)


def sequence_route(
    sequence: str, n_frames: int, seed: int = 0, spec: routes.RouteSpec = routes.DEFAULT_SPEC
) -> np.ndarray:
    """The camera poses T_w_c (n_frames, 4, 4) float64 of this sequence and seed."""
    rng = np.random.default_rng(_streams(sequence, seed)[0])
    return routes.make_route(rng, n_frames, spec.mix(sequence), spec.families)


def scene(
    sequence: str, n_frames: int, seed: int, spec: routes.RouteSpec = routes.DEFAULT_SPEC
) -> tuple[np.ndarray, World, np.random.Generator]:
    """The seeded route poses (N, 4, 4), world and sensor-noise generator of one sequence."""
    _, world_seq, noise_seq = _streams(sequence, seed)
    poses = sequence_route(sequence, n_frames, seed, spec)
    return poses, build_world(np.random.default_rng(world_seq), poses), np.random.default_rng(noise_seq)
