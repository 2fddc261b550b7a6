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

Sequences 00-10 drive a mix of town, residential, arterial and country roads; 11 and 12, the
unseen-motion split, drive stop-and-go traffic and expressways, families no other sequence drives.

The modules, each after what it holds:

- :mod:`~lossvo.data.synthetic.routes`: route families, the manoeuvre planner and the route poses;
- :mod:`~lossvo.data.synthetic.camera`: the intrinsics at the rendered size and calib.txt;
- :mod:`~lossvo.data.synthetic.textures`: the periodic texture tiles and their mip-mapped atlas;
- :mod:`~lossvo.data.synthetic.world`: the town around a route, and each sequence's seeded scene;
- :mod:`~lossvo.data.synthetic.render`: the ray-casting renderer;
- :mod:`~lossvo.data.synthetic.parameters`: sequences, frame counts and image sizes, with their checks;
- :mod:`~lossvo.data.synthetic.manifest`: the manifest, and which sequences of a dataset can be reused;
- :mod:`~lossvo.data.synthetic.platforms`: handheld, flying, drone and underwater motion along a route;
- :mod:`~lossvo.data.synthetic.layouts`: the TUM RGB-D, EuRoC, TartanAir and MIMIR layouts (cameras,
  clocks, files; :func:`sequence_name`);
- :mod:`~lossvo.data.synthetic.writer`: rendering sequences into a dataset (:func:`generate`,
  :func:`ensure_dataset`, ``layout=``, ``scale=``);
- :mod:`~lossvo.data.synthetic.cli`: the command line (an entry point, not imported here),
  ``python -m lossvo.data.synthetic --out DIR [--layout kitti|tum|euroc|tartanair|mimir] [--sequences 00,07]
  [--frames N] [--scale F | --height H --width W] [--seed S]`` (docs/data.md, "Other layouts").
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
