"""Platforms other than the car (handheld, flying, drone, underwater) moving along a town's route as
continuous functions of time: the route's path travelled at the platform's own speed (a cubic spline of its
positions, a slerp of its attitudes) plus seeded sinusoidal sway, rise, look-around and shake. Town axes
and units (x right, y down, z forward; m, s, rad); docs/data.md, "Other layouts"."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation, Slerp

from lossvo.console import UserError


@dataclass(frozen=True)
class Platform:
    """How a platform moves: mean speed (m/s) and the relative amplitude (< 1) of its variation; sway and
    rise (m; the camera climbs between 0 and rise above the route); look (yaw, pitch, roll amplitudes,
    rad); shake (rad, m); each wave's band (low, high) in Hz."""

    speed: float
    speed_wave: float
    speed_band: tuple[float, float]
    sway: float
    rise: float
    motion_band: tuple[float, float]
    look: tuple[float, float, float]
    look_band: tuple[float, float]
    shake_angle: float
    shake_offset: float
    shake_band: tuple[float, float]


DEG = math.pi / 180
PLATFORMS = {
    "handheld": Platform(0.5, 0.6, (0.05, 0.15), 0.15, 0.15, (0.05, 0.2),
                         (15 * DEG, 6 * DEG, 3 * DEG), (0.08, 0.2), 0.3 * DEG, 0.004, (0.8, 2.0)),
    "flying": Platform(1.0, 0.5, (0.03, 0.1), 0.6, 3.0, (0.03, 0.08),
                       (12 * DEG, 6 * DEG, 8 * DEG), (0.05, 0.15), 0.15 * DEG, 0.003, (2.0, 5.0)),
    "drone": Platform(1.5, 0.4, (0.03, 0.1), 0.8, 2.0, (0.02, 0.06),
                      (15 * DEG, 6 * DEG, 6 * DEG), (0.03, 0.1), 0.0, 0.0, (1.0, 2.0)),
    "auv": Platform(0.3, 0.3, (0.02, 0.05), 0.3, 1.0, (0.01, 0.04),
                    (5 * DEG, 2 * DEG, 2 * DEG), (0.02, 0.05), 0.05 * DEG, 0.002, (0.2, 0.5)),
}  # fmt: skip
"""The platforms of TUM RGB-D (handheld), EuRoC (flying), TartanAir (drone) and MIMIR (auv)."""

WAVE_TERMS = 3
"""Sinusoids summed in each wave."""


@dataclass(frozen=True)
class Wave:
    """A bounded smooth function of time: sum_i a_i sin(2 pi f_i t + phi_i), |value| <= sum a_i; arrays
    (..., WAVE_TERMS) of amplitudes, frequencies (Hz) and phases (rad), leading axes one per output."""

    amplitude: np.ndarray
    frequency: np.ndarray
    phase: np.ndarray

    def __call__(self, t: np.ndarray) -> np.ndarray:
        """(N, ...) values at times t (N,) seconds."""
        angle = 2 * np.pi * self.frequency * t.reshape(-1, *[1] * self.frequency.ndim) + self.phase
        return (self.amplitude * np.sin(angle)).sum(-1)

    def integral(self, t: np.ndarray) -> np.ndarray:
        """(N, ...) integral of the wave from 0 to t (N,) seconds."""
        omega = 2 * np.pi * self.frequency
        angle = omega * t.reshape(-1, *[1] * self.frequency.ndim) + self.phase
        return (self.amplitude / omega * (np.cos(self.phase) - np.cos(angle))).sum(-1)


def wave(rng: np.random.Generator, amplitude: np.ndarray | list[float], band: tuple[float, float]) -> Wave:
    """A seeded :class:`Wave` per entry of amplitude: WAVE_TERMS random frequencies in band (Hz) and
    phases, the terms' amplitudes summing to amplitude."""
    amplitude = np.asarray(amplitude, np.float64)
    shape = (*amplitude.shape, WAVE_TERMS)
    weights = rng.uniform(0.5, 1.0, shape)
    weights /= weights.sum(-1, keepdims=True)
    return Wave(amplitude[..., None] * weights, rng.uniform(*band, shape), rng.uniform(0, 2 * np.pi, shape))


@dataclass(frozen=True)
class Trajectory:
    """A platform's camera poses along a route (N, 4, 4) of 10 Hz car poses, a function of time (s >= 0);
    motion: the (sway, rise) waves."""

    route: np.ndarray
    platform: Platform
    speed: Wave
    motion: Wave
    look: Wave
    shake_angle: Wave
    shake_offset: Wave

    def distance(self, t: np.ndarray) -> np.ndarray:
        """(N,) metres travelled along the route's path at times t (N,) seconds (increasing in t)."""
        return self.platform.speed * (t + self.speed.integral(t)[:, 0])

    def poses(self, t: np.ndarray) -> np.ndarray:
        """(N, 4, 4) float64 camera poses T_w_c at times t (N,) seconds."""
        t = np.asarray(t, np.float64)
        tau = route_parameter(self.route, self.distance(t))
        frames = np.arange(len(self.route), dtype=np.float64)
        R_route = Slerp(frames, Rotation.from_matrix(self.route[:, :3, :3]))(tau)
        position = CubicSpline(frames, self.route[:, :3, 3])(tau)
        sway, rise = self.motion(t).T
        position += R_route.apply(np.stack([sway, np.zeros_like(sway), np.zeros_like(sway)], 1))
        position[:, 1] -= 0.5 * (self.platform.rise + rise)  # between 0 and rise metres up (y is down)
        look = Rotation.from_euler("YXZ", self.look(t))
        R = R_route * look * Rotation.from_rotvec(self.shake_angle(t))
        poses = np.tile(np.eye(4), (len(t), 1, 1))
        poses[:, :3, :3] = R.as_matrix()
        poses[:, :3, 3] = position + R.apply(self.shake_offset(t))
        return poses


def route_parameter(route: np.ndarray, distance: np.ndarray) -> np.ndarray:
    """(N,) route parameters (fractional frames) at distances (N,) m along its path; UserError past it."""
    steps = np.linalg.norm(np.diff(route[:, :3, 3], axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(steps)])
    if distance.max() > arc[-1]:
        raise UserError(f"route of {arc[-1]:.1f} m is shorter than the {distance.max():.1f} m travelled")
    moving = np.concatenate([[True], steps > 1e-9])  # np.interp needs strictly increasing arc lengths
    return np.interp(distance, arc[moving], np.flatnonzero(moving).astype(np.float64))


def trajectory(route: np.ndarray, platform: Platform, rng: np.random.Generator) -> Trajectory:
    """A seeded trajectory of platform along route (N, 4, 4)."""
    p = platform
    return Trajectory(
        route=route,
        platform=p,
        speed=wave(rng, [p.speed_wave], p.speed_band),
        motion=wave(rng, [p.sway, p.rise], p.motion_band),
        look=wave(rng, list(p.look), p.look_band),
        shake_angle=wave(rng, np.full(3, p.shake_angle / math.sqrt(3)), p.shake_band),
        shake_offset=wave(rng, np.full(3, p.shake_offset / math.sqrt(3)), p.shake_band),
    )


def max_distance(platform: Platform, duration: float) -> float:
    """Metres a platform travels at most in duration seconds (its speed wave at its peak throughout)."""
    return platform.speed * (1.0 + platform.speed_wave) * duration
