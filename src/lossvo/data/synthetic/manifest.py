"""The manifest, ``lossvo_synthetic.json`` at a dataset's root: what the dataset was rendered with and the
frames of each sequence; written last, so a dataset with one is complete (docs/data.md)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from lossvo.console import UserError
from lossvo.data.synthetic import layouts, routes
from lossvo.data.synthetic.camera import CameraRange

MANIFEST = "lossvo_synthetic.json"
RENDERING = "lossvo_synthetic.rendering"
"""Present while a render of lossvo's is unfinished, so a later render may write into its folder."""
VERSION = 2
"""Bumped whenever the rendered content changes, so that ensure_dataset renders old datasets again."""


@dataclass(frozen=True)
class Rendering:
    """What every sequence of one dataset is rendered with: (height, width) pixels, the seed, the route
    families and mixes, the layout and the ranges each sequence's camera is drawn from (None: KITTI's)."""

    height: int
    width: int
    seed: int
    spec: routes.RouteSpec
    layout: str = "kitti"
    cameras: CameraRange | None = None

    def header(self) -> dict:
        """The manifest entries every sequence shares, JSON-normalised; "layout" and "cameras" only where
        they are not KITTI's."""
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
    """The manifest of a complete dataset under root, or None (absent or unreadable)."""
    try:
        manifest = json.loads((Path(root) / MANIFEST).read_text())
    except (OSError, ValueError):
        return None
    return manifest if isinstance(manifest, dict) else None


def complete_sequences(root: Path, shared: dict) -> dict[str, int]:
    """{sequence: frames} of the sequences whose files are all there, in a dataset under root whose
    manifest has the entries shared (:meth:`Rendering.header`); {} for any other root."""
    manifest = read_manifest(root)
    if manifest is None or any(manifest.get(k) != shared.get(k) for k in {*shared, "layout", "cameras"}):
        return {}
    layout = shared.get("layout", "kitti")
    return {
        s: n for s, n in manifest.get("frames", {}).items() if layouts.sequence_complete(root, layout, s, n)
    }


def check_ours(root: Path) -> None:
    """UserError where root is a file, or a folder holding files that lossvo did not render (neither
    :data:`MANIFEST` nor :data:`RENDERING`)."""
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
