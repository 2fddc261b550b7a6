"""Which metric axioms each rotation distance satisfies, checked numerically in float64 on seeded random
rotations and on the triples where a failure shows first, the worst case kept as evidence: non-negativity,
identity on rotations (whichever Euler triple or quaternion sign writes them), symmetry, the triangle
inequality. ``python -m lossvo.axioms`` prints the table; docs/losses.md explains it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor

from lossvo import geometry as g

TOLERANCE = 1e-9
"""Float64 slack: an axiom fails only if it is violated by more than this."""

AXIOMS = ("non-negativity", "identity on rotations", "symmetry", "triangle inequality")


# --------------------------------------------------------------------------------------------------
# Representations: how a rotation matrix is written, and its other writings of the same rotation
# --------------------------------------------------------------------------------------------------


def _euler_aliases(e: Tensor) -> dict[str, Tensor]:
    """Other Euler triples of the same rotations: yaw + 2 pi, and (yaw + pi, pi - pitch, roll + pi)."""
    yaw, pitch, roll = e.unbind(-1)
    return {
        "φ vs (yaw + 2π, pitch, roll)": torch.stack((yaw + 2 * math.pi, pitch, roll), dim=-1),
        "φ vs (yaw + π, π − pitch, roll + π)": torch.stack(
            (yaw + math.pi, math.pi - pitch, roll + math.pi), dim=-1
        ),
    }


@dataclass(frozen=True)
class Representation:
    """A way of writing rotations: from (..., 3, 3) matrices, and the other writings of each one."""

    name: str
    from_matrix: Callable[[Tensor], Tensor]
    aliases: Callable[[Tensor], dict[str, Tensor]]


EULER = Representation("Euler (yaw, pitch, roll)", g.matrix_to_euler, _euler_aliases)
QUATERNION = Representation("unit quaternion", g.matrix_to_quat, lambda q: {"q vs −q": -q})
MATRIX = Representation("rotation matrix", lambda R: R, lambda R: {})


@dataclass(frozen=True)
class Distance:
    """A distance between two batches of rotations written in ``representation``."""

    name: str
    formula: str
    representation: Representation
    fn: Callable[[Tensor, Tensor], Tensor]
    note: str


def _squared(fn: Callable[[Tensor, Tensor], Tensor]) -> Callable[[Tensor, Tensor], Tensor]:
    return lambda a, b: fn(a, b).square()


def _naive_quat_distance(q_a: Tensor, q_b: Tensor) -> Tensor:
    return torch.linalg.vector_norm(q_a - q_b, dim=-1)


DISTANCES: tuple[Distance, ...] = (
    Distance(
        "Euler",
        "‖φ − φ̂‖",
        EULER,
        g.euler_distance,
        "A metric on angle triples in R³, not on rotations: one rotation has many triples.",
    ),
    Distance(
        "Euler² (euler loss)",
        "‖φ − φ̂‖²",
        EULER,
        _squared(g.euler_distance),
        "Squared: the triangle inequality fails too (at coordinate midpoints).",
    ),
    Distance(
        "quaternion, one sign",
        "‖q − q̂‖",
        QUATERNION,
        _naive_quat_distance,
        "Not sign-invariant: q and −q, one rotation, are 2 apart.",
    ),
    Distance(
        "quaternion, min over sign",
        "min±‖q ∓ q̂‖",
        QUATERNION,
        g.quat_distance,
        "= 2 sin(θ/4): a metric on SO(3); on unit quaternions only a pseudo-metric (d(q, −q) = 0).",
    ),
    Distance(
        "quaternion² (quat loss)",
        "min±‖q ∓ q̂‖²",
        QUATERNION,
        _squared(g.quat_distance),
        "= 4 sin²(θ/4): squared, so the triangle inequality fails (at geodesic midpoints).",
    ),
    Distance(
        "chordal",
        "‖R − R̂‖_F",
        MATRIX,
        g.so3_chordal_distance,
        "= 2√2 sin(θ/2): a metric (the Frobenius norm of R⁹ restricted to SO(3)).",
    ),
    Distance(
        "chordal² (chordal loss)",
        "‖R − R̂‖_F²",
        MATRIX,
        _squared(g.so3_chordal_distance),
        "= 8 sin²(θ/2): squared, so the triangle inequality fails (at geodesic midpoints).",
    ),
    Distance(
        "geodesic",
        "θ = ∠(Rᵀ R̂)",
        MATRIX,
        g.so3_geodesic_distance,
        "The Riemannian distance of SO(3): a metric.",
    ),
    Distance(
        "geodesic² (geodesic loss)",
        "θ²",
        MATRIX,
        _squared(g.so3_geodesic_distance),
        "Squared: the triangle inequality fails (at geodesic midpoints).",
    ),
)


# --------------------------------------------------------------------------------------------------
# Samples
# --------------------------------------------------------------------------------------------------


def random_rotations(n: int, generator: torch.Generator, max_angle: float = math.pi) -> Tensor:
    """(n, 3, 3) float64 rotations: uniform axes, angles uniform in [0, max_angle] radians."""
    axis = torch.randn(n, 3, generator=generator, dtype=torch.float64)
    axis = axis / torch.linalg.vector_norm(axis, dim=-1, keepdim=True)
    angle = max_angle * torch.rand(n, 1, generator=generator, dtype=torch.float64)
    return g.so3_exp(axis * angle)


def geodesic_midpoint(R_a: Tensor, R_b: Tensor) -> Tensor:
    """Midpoints ``R_a exp(log(R_aᵀ R_b) / 2)`` (..., 3, 3) of the shortest geodesics from R_a to R_b."""
    return R_a @ g.so3_exp(0.5 * g.so3_log(R_a.transpose(-1, -2) @ R_b))


@dataclass(frozen=True)
class Samples:
    """Float64 rotations: ``pairs`` (2, N, 3, 3) random; ``triples`` (3, M, 3, 3) whose middle rotation is
    on the geodesic between the outer two, or random."""

    pairs: Tensor
    triples: Tensor


def make_samples(n: int = 4096, seed: int = 0) -> Samples:
    """Random pairs, and triples: random, and midpoints of short (<= 0.2 rad), medium and long (up to pi)
    geodesics, where squared distances fail the triangle inequality first."""
    gen = torch.Generator().manual_seed(seed)
    pairs = torch.stack((random_rotations(n, gen), random_rotations(n, gen)))
    outer = []
    for max_angle in (0.2, 1.0, math.pi):
        R_a = random_rotations(n, gen)
        outer.append((R_a, R_a @ random_rotations(n, gen, max_angle)))
    R_x = torch.cat([a for a, _ in outer] + [random_rotations(n, gen)])
    R_z = torch.cat([b for _, b in outer] + [random_rotations(n, gen)])
    R_y = torch.cat((geodesic_midpoint(R_x[: 3 * n], R_z[: 3 * n]), random_rotations(n, gen)))
    return Samples(pairs, torch.stack((R_x, R_y, R_z)))


# --------------------------------------------------------------------------------------------------
# Checks: each returns whether the axiom holds on the samples, and the worst case as evidence
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Verdict:
    """Outcome of one axiom for one distance: ``holds`` and a one-line piece of ``evidence``."""

    holds: bool
    evidence: str


def check_non_negativity(d: Distance, s: Samples) -> Verdict:
    """``d(x, y) >= 0`` on random pairs."""
    rep = d.representation.from_matrix
    worst = d.fn(rep(s.pairs[0]), rep(s.pairs[1])).min().item()
    return Verdict(worst >= -TOLERANCE, f"min d = {worst:.3g}")


def check_identity(d: Distance, s: Samples) -> Verdict:
    """``d(x, x') = 0`` for every writing x' of x's rotation, and ``d > 0`` for different rotations."""
    rep = d.representation
    x = rep.from_matrix(s.pairs[0])
    same = {"x vs x": d.fn(x, x)} | {label: d.fn(x, a) for label, a in rep.aliases(x).items()}
    label, worst = max(((k, v.max().item()) for k, v in same.items()), key=lambda kv: kv[1])
    if worst > TOLERANCE:
        return Verdict(False, f"one rotation written as {label}: d up to {worst:.4g}")
    apart = g.so3_geodesic_distance(s.pairs[0], s.pairs[1]) > 1e-3
    least = d.fn(x, rep.from_matrix(s.pairs[1]))[apart].min().item()
    return Verdict(least > TOLERANCE, f"same rotation: d ≤ {worst:.1g}; different: d ≥ {least:.2g}")


def check_symmetry(d: Distance, s: Samples) -> Verdict:
    """``d(x, y) = d(y, x)`` on random pairs."""
    rep = d.representation.from_matrix
    x, y = rep(s.pairs[0]), rep(s.pairs[1])
    worst = (d.fn(x, y) - d.fn(y, x)).abs().max().item()
    return Verdict(worst <= TOLERANCE, f"max |d(x,y) − d(y,x)| = {worst:.1g}")


def check_triangle(d: Distance, s: Samples) -> Verdict:
    """``d(x, z) <= d(x, y) + d(y, z)`` on random and midpoint triples (the worst case is reported); in
    Euler coordinates also on (x, (x+z)/2, z), where a squared Euclidean distance fails."""
    x, y, z = (d.representation.from_matrix(R) for R in s.triples)
    if d.representation is EULER:
        x, y, z = torch.cat((x, x)), torch.cat((y, 0.5 * (x + z))), torch.cat((z, z))
    d_xz, d_xy, d_yz = d.fn(x, z), d.fn(x, y), d.fn(y, z)
    excess = d_xz - (d_xy + d_yz)
    i = int(excess.argmax())
    evidence = f"d(x,z) = {d_xz[i]:.4g} vs d(x,y) + d(y,z) = {d_xy[i] + d_yz[i]:.4g}"
    return Verdict(excess[i].item() <= TOLERANCE, evidence)


CHECKS: dict[str, Callable[[Distance, Samples], Verdict]] = {
    "non-negativity": check_non_negativity,
    "identity on rotations": check_identity,
    "symmetry": check_symmetry,
    "triangle inequality": check_triangle,
}


def check_all(samples: Samples | None = None) -> dict[str, dict[str, Verdict]]:
    """Every axiom for every distance in :data:`DISTANCES`: ``{distance name: {axiom: Verdict}}``."""
    s = make_samples() if samples is None else samples
    return {d.name: {axiom: CHECKS[axiom](d, s) for axiom in AXIOMS} for d in DISTANCES}


# --------------------------------------------------------------------------------------------------
# Table
# --------------------------------------------------------------------------------------------------


def classify(verdicts: dict[str, Verdict]) -> str:
    """Metric, pseudo-/semi-metric or neither, by which axioms hold."""
    holds = {axiom: v.holds for axiom, v in verdicts.items()}
    if all(holds.values()):
        return "metric"
    if holds["non-negativity"] and holds["symmetry"]:
        if not holds["triangle inequality"] and holds["identity on rotations"]:
            return "semimetric"
        return "not a function of rotations" if not holds["identity on rotations"] else "—"
    return "—"
