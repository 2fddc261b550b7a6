"""Synthetic KITTI-odometry dataset: a procedural town rendered along car-like routes, written in the KITTI
layout (or TUM, EuRoC, TartanAir, MIMIR) by :func:`generate`, ``lossvo_synthetic.json`` last (present =
complete). KITTI's conventions: camera x right, y down, z forward; the world is the first camera frame, the
ground the plane y = +1.65 m; frames rendered with exactly K = P2[:, :3]. Sequences 00-10 drive town,
residential, arterial and country roads; 11 and 12 (unseen motion) stop-and-go traffic and expressways.
"""

from lossvo.data.synthetic.camera import intrinsics
from lossvo.data.synthetic.layouts import LAYOUTS, sequence_name
from lossvo.data.synthetic.manifest import MANIFEST, VERSION, read_manifest
from lossvo.data.synthetic.parameters import DEFAULT_FRAMES, DEFAULT_HEIGHT, DEFAULT_WIDTH, SEQUENCES
from lossvo.data.synthetic.render import Renderer
from lossvo.data.synthetic.world import World, build_world, scene, sequence_route
from lossvo.data.synthetic.writer import ensure_dataset, generate

__all__ = [
    "DEFAULT_FRAMES",
    "DEFAULT_HEIGHT",
    "DEFAULT_WIDTH",
    "LAYOUTS",
    "MANIFEST",
    "SEQUENCES",
    "VERSION",
    "Renderer",
    "World",
    "build_world",
    "ensure_dataset",
    "generate",
    "intrinsics",
    "read_manifest",
    "scene",
    "sequence_name",
    "sequence_route",
]
