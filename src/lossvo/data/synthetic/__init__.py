"""Synthetic KITTI-odometry dataset: a procedural town rendered along car-like routes, written in the KITTI
layout (or TUM, EuRoC, TartanAir, MIMIR) by :func:`generate`; docs/data.md, "The synthetic renderer"."""

from lossvo.data.synthetic.camera import intrinsics
from lossvo.data.synthetic.layouts import sequence_name
from lossvo.data.synthetic.manifest import MANIFEST, read_manifest
from lossvo.data.synthetic.render import Renderer
from lossvo.data.synthetic.world import build_world, scene, sequence_route
from lossvo.data.synthetic.writer import (
    DEFAULT_FRAMES,
    DEFAULT_HEIGHT,
    DEFAULT_WIDTH,
    SEQUENCES,
    ensure_dataset,
    generate,
)

__all__ = [
    "DEFAULT_FRAMES",
    "DEFAULT_HEIGHT",
    "DEFAULT_WIDTH",
    "MANIFEST",
    "SEQUENCES",
    "Renderer",
    "build_world",
    "ensure_dataset",
    "generate",
    "intrinsics",
    "read_manifest",
    "scene",
    "sequence_name",
    "sequence_route",
]
