"""Car-like camera routes on the ground plane, drawn from route families: chains of manoeuvres (a
straight, then a turn, a lane change or a stop) under acceleration and braking limits, with hills and camber.
Units: metres, radians, frames (10 Hz), speeds in m/frame; poses T_w_c in KITTI's axes, the first the
identity, R = Ry(yaw) @ Rx(pitch) @ Rz(roll). The families and their motion statistics: docs/data.md."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from lossvo import geometry
from lossvo.checks import is_number
from lossvo.console import UserError
from lossvo.data.sequence import sequence_name

STRETCH = 60
"""Frames (at least) driven in one family before the next is drawn from the mix."""

ACCEL, BRAKE = 0.012, 0.02
"""Acceleration and braking limits, m/frame per frame (1.2 and 2.0 m/s^2)."""
LANE_WIDTH = 3.5
"""Metres of sideways displacement of a lane change."""
MAX_HEADING = math.radians(100)
"""Turns are steered back once the net heading passes this, so routes do not wind back on themselves."""
MAX_TILT = 0.045
"""Radians: pitch and roll (grade, braking, camber, cornering) are clipped to this (2.6 degrees)."""


@dataclass(frozen=True)
class Family:
    """Ranges the manoeuvres of one kind of driving are drawn from, uniformly: cruise (m/frame), straight
    (m), the probabilities of a turn, lane change or stop after a straight, turn_angle (degrees), turn_radius
    (m, mean over the turn), turn_speed (m/frame), stop_frames; hill (m) and camber (rad) amplitudes."""

    name: str
    description: str
    cruise: tuple[float, float]
    straight: tuple[float, float]
    turn: float
    turn_angle: tuple[float, float]
    turn_radius: tuple[float, float]
    turn_speed: tuple[float, float]
    lane_change: float = 0.0
    stop: float = 0.0
    stop_frames: tuple[int, int] = (10, 30)
    hill: float = 0.0
    camber: float = 0.0

    def __post_init__(self) -> None:
        """UserError naming the first impossible parameter (negative speed, zero radius, ...)."""
        where = f"route family {self.name!r}"
        for key in ("cruise", "straight", "turn_angle", "turn_radius", "turn_speed", "stop_frames"):
            lo, hi = getattr(self, key)
            if not (0 < lo <= hi and math.isfinite(hi)):
                raise UserError(f"{where}: {key} must be a range 0 < low <= high, got {(lo, hi)}")
        for key in ("turn", "lane_change", "stop"):
            if not 0.0 <= getattr(self, key) <= 1.0:
                raise UserError(f"{where}: {key} must be a probability in [0, 1], got {getattr(self, key)}")
        if self.turn + self.lane_change + self.stop > 1.0:
            raise UserError(f"{where}: turn + lane_change + stop must be <= 1")
        for key in ("hill", "camber"):
            if not 0.0 <= getattr(self, key) < 1.0:
                raise UserError(f"{where}: {key} must be in [0, 1), got {getattr(self, key)}")


FAMILIES: dict[str, Family] = {
    f.name: f
    for f in (
        Family(
            "town",
            "city streets: right-angle corners at crossings, stops at lights",
            cruise=(0.5, 1.0),
            straight=(10, 60),
            turn=0.65,
            turn_angle=(75, 105),
            turn_radius=(10, 22),
            turn_speed=(0.35, 0.6),
            lane_change=0.1,
            stop=0.25,
            stop_frames=(5, 40),
            camber=0.01,
        ),
        Family(
            "residential",
            "quiet side streets at low speed: crossings, parked-car stops",
            cruise=(0.15, 0.5),
            straight=(10, 50),
            turn=0.5,
            turn_angle=(60, 100),
            turn_radius=(8, 20),
            turn_speed=(0.15, 0.35),
            stop=0.2,
            stop_frames=(5, 30),
        ),
        Family(
            "arterial",
            "fast multi-lane roads: long straights, wide curves, lane changes",
            cruise=(0.9, 1.4),
            straight=(50, 200),
            turn=0.5,
            turn_angle=(20, 70),
            turn_radius=(40, 150),
            turn_speed=(0.7, 1.1),
            lane_change=0.3,
            stop=0.05,
            stop_frames=(10, 25),
            hill=0.15,
        ),
        Family(
            "country",
            "winding roads over gentle hills, with camber",
            cruise=(0.6, 1.1),
            straight=(10, 40),
            turn=0.85,
            turn_angle=(20, 120),
            turn_radius=(15, 60),
            turn_speed=(0.5, 0.85),
            hill=0.35,
            camber=0.025,
        ),
        Family(
            "stop_and_go",
            "slow urban traffic: frequent long stops, tight corners at walking pace",
            cruise=(0.2, 0.5),
            straight=(8, 25),
            turn=0.35,
            turn_angle=(85, 95),
            turn_radius=(9, 14),
            turn_speed=(0.2, 0.3),
            stop=0.6,
            stop_frames=(10, 40),
        ),
        Family(
            "expressway",
            "fast straight roads: very wide curves, lane changes, no stops",
            cruise=(1.2, 1.45),
            straight=(100, 300),
            turn=0.4,
            turn_angle=(5, 20),
            turn_radius=(400, 1200),
            turn_speed=(1.15, 1.4),
            lane_change=0.5,
        ),
    )
}
"""The route families by name."""

TRAINING_MIX: dict[str, float] = {"town": 0.4, "residential": 0.15, "arterial": 0.25, "country": 0.2}
UNSEEN_MIX: dict[str, float] = {"stop_and_go": 0.5, "expressway": 0.5}
UNSEEN_SEQUENCES = ("11", "12")
"""The unseen-motion sequences: routes of families that no other sequence drives."""
MIXES: dict[str, dict[str, float]] = {
    **{sequence_name(i): TRAINING_MIX for i in range(11)},
    **dict.fromkeys(UNSEEN_SEQUENCES, UNSEEN_MIX),
}
"""Family mix of each sequence; sequences not listed drive TRAINING_MIX."""


def check_mix(mix: Mapping[str, float], families: Mapping[str, Family] = FAMILIES) -> dict[str, float]:
    """The mix with weights normalised to sum 1; UserError for unknown families or bad weights."""
    if not isinstance(mix, Mapping):
        raise UserError(f"route mix: expected a mapping of family name to weight, got {mix!r}")
    unknown = [name for name in mix if name not in families]
    if unknown:
        raise UserError(f"unknown route family {unknown[0]!r}: expected one of {', '.join(families)}")
    weights = [w for w in mix.values() if is_number(w)]
    if len(weights) < len(mix) or not all(w >= 0 and math.isfinite(w) for w in weights) or sum(weights) <= 0:
        raise UserError(f"route mix: expected non-negative weights with a positive sum, got {dict(mix)}")
    return {name: float(w) / sum(weights) for name, w in mix.items()}


@dataclass(frozen=True)
class RouteSpec:
    """What the routes of a dataset are drawn from: the families by name and each sequence's mix
    (sequences not listed drive :data:`TRAINING_MIX`)."""

    families: Mapping[str, Family]
    mixes: Mapping[str, Mapping[str, float]]

    def mix(self, sequence: str) -> dict[str, float]:
        """The family mix (name -> weight) the routes of this sequence are drawn from."""
        return dict(self.mixes.get(sequence, TRAINING_MIX))

    def manifest(self) -> dict:
        """A JSON-able description (recorded with a rendered dataset, so a change re-renders it)."""
        return {
            "families": {n: dataclasses.asdict(f) for n, f in sorted(self.families.items())},
            "mixes": {s: dict(m) for s, m in sorted(self.mixes.items())},
        }


FIELDS = tuple(f.name for f in dataclasses.fields(Family) if f.name != "name")
REQUIRED = tuple(f.name for f in dataclasses.fields(Family)[1:] if f.default is dataclasses.MISSING)
"""The parameters a new family needs."""


def route_spec(
    families: Mapping[str, Mapping] | None = None,
    mixes: Mapping[str, Mapping[str, float]] | None = None,
    prefix: str = "",
) -> RouteSpec:
    """The default RouteSpec with families added or changed (name -> the parameters that change, all
    :data:`REQUIRED` for a new one) and sequences' mixes replaced; UserError naming the key after prefix."""
    table = dict(FAMILIES)
    for name, params in (families or {}).items():
        where = f"{prefix}route_families.{name}"
        if not isinstance(params, Mapping):
            raise UserError(f"{where}: expected a mapping of parameters, got {params!r}")
        unknown = [k for k in params if k not in FIELDS]
        if unknown:
            raise UserError(
                f"{where}: unknown parameter {unknown[0]!r} (expected some of {', '.join(FIELDS)})"
            )
        values: dict[str, Any] = {  # config values; Family's own checks validate them
            k: tuple(v) if isinstance(v, list | tuple) else v for k, v in params.items()
        }
        base = dataclasses.asdict(table[name]) if name in table else {"name": str(name)}
        missing = [k for k in REQUIRED if k not in {**base, **values}]
        if missing:
            raise UserError(f"{where}: a new family needs {', '.join(missing)}")
        table[name] = Family(**{**base, **values})
    chosen = dict(MIXES)
    for sequence, mix in (mixes or {}).items():
        key = sequence_name(sequence)
        try:
            chosen[key] = check_mix(mix, table)
        except UserError as err:
            raise UserError(f"{prefix}route_mixes.{key}: {err}") from None
    return RouteSpec(table, chosen)


@dataclass
class Plan:
    """Per-frame target speed (n,) m/frame and family (n,) of a route, and the events that rotate the car:
    (first frame, end frame, "turn" | "lane", signed rad | m)."""

    target: np.ndarray
    family: np.ndarray
    events: list[tuple[int, int, str, float]]


def _turn_sign(rng: np.random.Generator, heading: float) -> float:
    """+1 (right) or -1 (left), steering the net heading back once it passes MAX_HEADING."""
    if abs(heading) > MAX_HEADING:
        return -math.copysign(1.0, heading)
    return 1.0 if rng.random() < 0.5 else -1.0


def plan_route(
    rng: np.random.Generator, n: int, mix: Mapping[str, float], families: Mapping[str, Family] = FAMILIES
) -> Plan:
    """Manoeuvres drawn from the mix until at least n frames are planned, to the end of the last one."""
    weights = check_mix(mix, families)
    names, p = list(weights), np.array(list(weights.values()))
    speeds: list[np.ndarray] = []
    driven: list[str] = []
    events: list[tuple[int, int, str, float]] = []
    total, heading, stretch_end, family = 0, 0.0, 0, families[names[0]]
    while total < n:
        if total >= stretch_end:
            family = families[names[int(rng.choice(len(names), p=p))]]
            stretch_end = total + STRETCH
        cruise = rng.uniform(*family.cruise)
        frames = max(1, round(rng.uniform(*family.straight) / cruise))
        speeds.append(np.full(frames, cruise))
        driven += [family.name] * frames
        total += frames
        u = rng.random()
        if u < family.turn:
            angle = math.radians(rng.uniform(*family.turn_angle)) * _turn_sign(rng, heading)
            speed = min(cruise, rng.uniform(*family.turn_speed))
            frames = max(4, round(rng.uniform(*family.turn_radius) * abs(angle) / speed))
            events.append((total, total + frames, "turn", angle))
            heading += angle
        elif u < family.turn + family.lane_change:
            speed = cruise
            frames = max(10, round(rng.uniform(30.0, 70.0) / speed))
            events.append((total, total + frames, "lane", LANE_WIDTH * (1.0 if rng.random() < 0.5 else -1.0)))
        elif u < family.turn + family.lane_change + family.stop:
            speed, frames = 0.0, int(rng.integers(family.stop_frames[0], family.stop_frames[1] + 1))
        else:
            continue
        speeds.append(np.full(frames, speed))
        driven += [family.name] * frames
        total += frames
    return Plan(np.concatenate(speeds), np.array(driven), events)


def speed_profile(target: np.ndarray, accel: float = ACCEL, brake: float = BRAKE) -> np.ndarray:
    """Speeds (n,) m/frame as close to target (n,) as the acceleration (forward pass) and braking
    (backward pass) limits allow; never above the target, exactly 0 where the car stands."""
    v = target.astype(np.float64).copy()
    for k in range(1, len(v)):  # sequential by nature: each speed depends on the previous one
        v[k] = min(v[k], v[k - 1] + accel)
    for k in range(len(v) - 2, -1, -1):
        v[k] = min(v[k], v[k + 1] + brake)
    return v


def yaw_rates(speed: np.ndarray, events: list[tuple[int, int, str, float]]) -> np.ndarray:
    """Yaw change per frame (n,) rad of the turn and lane-change events at speeds (n,) m/frame.

    A turn of angle a over frames [i, j) turns by a * w_k / sum(w), w_k = v_k sin^2(pi u_k). A lane change
    heads away by h_k = A sin^2(pi k / (N - 1)) and back, A such that sum(v_k h_k) is its signed width.
    """
    rate = np.zeros(len(speed))
    for start, end, kind, amount in events:
        v = speed[start:end]
        if kind == "turn":
            w = v * np.sin(np.pi * (np.arange(len(v)) + 0.5) / (end - start)) ** 2
            rate[start : start + len(v)] += amount * w / max(w.sum(), 1e-9)
        else:  # the heading profile is 0 at the first and the last frame: back on the original heading
            shape = np.sin(np.pi * np.arange(len(v)) / max(end - start - 1, 1)) ** 2
            heading = amount * shape / max((v * shape).sum(), 1e-9)
            rate[start : start + len(v)] += np.diff(np.concatenate([[0.0], heading]))
    return rate


def _gaussian(sigma: float) -> np.ndarray:
    """Unnormalised Gaussian kernel (2 h + 1,) of std sigma samples, h = max(1, int(3 sigma))."""
    half = max(1, int(3 * sigma))
    return np.exp(-0.5 * (np.arange(-half, half + 1) / sigma) ** 2)


def _smooth_noise(rng: np.random.Generator, n: int, std: float, sigma: float) -> np.ndarray:
    """(n,) smooth zero-mean random signal of the given std, correlated over about sigma samples."""
    kernel = _gaussian(sigma)
    kernel /= np.sqrt((kernel**2).sum())
    return std * np.convolve(rng.standard_normal(n + len(kernel) - 1), kernel, mode="valid")


def _blend(driven: np.ndarray, families: Mapping[str, Family], key: str, sigma: float = 15.0) -> np.ndarray:
    """(n,) per-frame family parameter ``key`` (e.g. hill), smoothed over family changes."""
    values = np.array([getattr(families[name], key) for name in driven], dtype=np.float64)
    kernel = _gaussian(sigma)
    return np.convolve(np.pad(values, len(kernel) // 2, mode="edge"), kernel / kernel.sum(), mode="valid")


def undulation(
    rng: np.random.Generator, wavelength: tuple[float, float]
) -> Callable[[np.ndarray], np.ndarray]:
    """A profile f(distance) (n,) -> (n,) in [-1, 1] of the distance travelled (m): the mean of two
    sinusoids of wavelengths (m) drawn from the range."""
    lengths, phases = rng.uniform(*wavelength, 2), rng.uniform(0, 2 * np.pi, 2)

    def profile(distance: np.ndarray) -> np.ndarray:
        return 0.5 * np.sin(2 * np.pi * distance[:, None] / lengths + phases).sum(-1)

    return profile


def make_route(
    rng: np.random.Generator,
    n_frames: int,
    mix: Mapping[str, float] = TRAINING_MIX,
    families: Mapping[str, Family] = FAMILIES,
) -> np.ndarray:
    """Camera poses T_w_c (n_frames, 4, 4) float64 of a car driving a route drawn from the mix: the planned
    manoeuvres plus speed noise, lane wobble, suspension pitch and roll, hills, camber and bobbing."""
    plan = plan_route(rng, n_frames, mix, families)
    n = len(plan.target)
    moving = plan.target > 0
    speed = speed_profile(plan.target * np.where(moving, 1.0 + _smooth_noise(rng, n, 0.03, 6.0), 0.0))
    engine = np.minimum(1.0, speed / 0.2)  # small motions fade out as the car comes to a stop
    yaw_rate = yaw_rates(speed, plan.events) + speed * _smooth_noise(rng, n, 0.002, 4.0)
    yaw = np.concatenate([[0.0], np.cumsum(yaw_rate)[:-1]])
    distance = np.concatenate([[0.0], np.cumsum(speed)[:-1]])
    hill, rise = _blend(plan.family, families, "hill"), undulation(rng, (80.0, 250.0))
    height = hill * rise(distance)
    grade = np.arctan(hill * (rise(distance + 0.5) - rise(distance - 0.5)))  # 1 m central difference
    pitch = grade + 0.25 * np.gradient(speed) + engine * _smooth_noise(rng, n, math.radians(0.25), 2.0)
    roll = (
        _blend(plan.family, families, "camber") * undulation(rng, (150.0, 400.0))(distance)
        - 0.15 * speed * yaw_rate
    )
    roll = roll + engine * _smooth_noise(rng, n, math.radians(0.2), 2.0)
    pitch, roll = np.clip(pitch, -MAX_TILT, MAX_TILT), np.clip(roll, -MAX_TILT, MAX_TILT)
    bob = engine * _smooth_noise(rng, n, 0.01, 2.0)
    heading = 0.5 * (yaw[:-1] + yaw[1:])
    steps = speed[:-1, None] * np.stack([np.sin(heading), np.cos(heading)], -1)
    xz = np.concatenate([np.zeros((1, 2)), np.cumsum(steps, 0)])
    poses = np.tile(np.eye(4), (n, 1, 1))
    angles = np.stack([yaw, pitch - pitch[0], roll - roll[0]], -1)
    poses[:, :3, :3] = geometry.euler_to_matrix(torch.from_numpy(angles)).numpy()
    poses[:, :3, 3] = np.stack([xz[:, 0], -(height - height[0]) + bob - bob[0], xz[:, 1]], -1)
    return poses[:n_frames]


DEFAULT_SPEC = route_spec()
"""The families and mixes of the embedded dataset."""
