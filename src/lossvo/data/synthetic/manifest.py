"""The manifest, ``lossvo_synthetic.json`` at a dataset's root: the parameters the dataset was rendered
with (generator version, image size, seed, route families and mixes) and the frames of each sequence.

It is written last, so a dataset with a manifest is complete; a dataset whose manifest has the same
header as a request is reused, sequence by sequence.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from lossvo.console import UserError
from lossvo.data import kitti
from lossvo.data.synthetic import layouts, routes
from lossvo.data.synthetic.camera import CameraRange

MANIFEST = "lossvo_synthetic.json"
RENDERING = "lossvo_synthetic.rendering"
"""Written first and removed once the manifest is written: a folder holding it is a render of lossvo's
that was interrupted, so a later render may write into it."""
VERSION = 2
"""Bumped whenever the rendered content changes, so that ensure_dataset regenerates old datasets."""


@dataclass(frozen=True)
class Rendering:
    """What every sequence of one dataset is rendered with: (height, width) pixels, the seed, the route
    families and mixes, the layout and, in the KITTI layout, the ranges each sequence's camera is drawn from
    (None: KITTI's camera)."""

    height: int
    width: int
    seed: int
    spec: routes.RouteSpec
    layout: str = "kitti"
    cameras: CameraRange | None = None

    def header(self) -> dict:
        """The manifest entries that every sequence of the dataset shares (JSON-normalised, so that they
        compare equal to the ones read back from a manifest); a "layout" entry for layouts other than kitti
        (a manifest without one is a KITTI-layout dataset), a "cameras" entry for cameras drawn per sequence
        (without one: KITTI's camera)."""
        entries = {
            "generator": "lossvo.data.synthetic",
            "version": VERSION,
            "height": self.height,
            "width": self.width,
            "seed": self.seed,
            "routes": self.spec.manifest(),
        }
        if self.layout != "kitti":
            entries["layout"] = self.layout
        if self.cameras is not None:
            entries["cameras"] = self.cameras.manifest()
        return json.loads(json.dumps(entries))


def read_manifest(root: Path) -> dict | None:
    """The parameters a complete dataset under root was generated with, or None (absent or unreadable)."""
    try:
        manifest = json.loads((Path(root) / MANIFEST).read_text())
    except (OSError, ValueError):
        return None
    return manifest if isinstance(manifest, dict) else None


def sequence_complete(root: Path, sequence: str, n_frames: int) -> bool:
    """Whether root holds sequence with its poses, calib, times and n_frames images."""
    seq = root / "sequences" / sequence
    if not all(p.is_file() for p in (kitti.pose_path(root, sequence), seq / "calib.txt", seq / "times.txt")):
        return False
    return sum(1 for _ in (seq / "image_2").glob("*.png")) == n_frames


def complete_sequences(root: Path, shared: dict) -> dict[str, int]:
    """{sequence: frames} of the dataset under root whose manifest has the entries shared
    (:meth:`Rendering.header`: the same layout), for the sequences it lists whose files are all present;
    {} for any other root."""
    manifest = read_manifest(root)
    layout = shared.get("layout", "kitti")
    if (
        manifest is None
        or any(manifest.get(k) != v for k, v in shared.items())
        or manifest.get("layout", "kitti") != layout
        or manifest.get("cameras") != shared.get("cameras")
    ):
        return {}
    frames = manifest.get("frames", {})
    if layout == "kitti":
        return {s: n for s, n in frames.items() if sequence_complete(root, s, n)}
    return {s: n for s, n in frames.items() if layouts.sequence_complete(root, layout, s, n)}


def check_ours(root: Path) -> None:
    """``UserError`` where ``root`` is a file, or a folder holding files that lossvo did not render (neither
    :data:`MANIFEST` nor :data:`RENDERING`): lossvo writes only into folders it made."""
    root = Path(root)
    if root.exists() and not root.is_dir():
        raise UserError(f"{root}: is a file: give a new or empty folder for the synthetic dataset")
    if not root.is_dir() or (root / MANIFEST).is_file() or (root / RENDERING).is_file():
        return
    if any(root.iterdir()):
        raise UserError(
            f"{root}: holds files that lossvo did not render (no {MANIFEST}): give a new or empty folder "
            "for the synthetic dataset; lossvo does not write into data it did not make"
        )
