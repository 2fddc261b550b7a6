"""The bird's-eye trajectory plot that the evaluation and the report draw, on Agg canvases without pyplot
state (safe in threads); matplotlib is imported inside the functions, loaded only when plotting.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lossvo.atomic import atomic_path

if TYPE_CHECKING:
    from matplotlib.figure import Figure

DPI = 100
"""Resolution of every saved PNG (pixels per inch; figure sizes are in inches)."""
GROUND_TRUTH_STYLE: Mapping[str, Any] = {"color": "black", "lw": 2.0}
START_STYLE: Mapping[str, Any] = {"color": "tab:green", "ms": 5}


def new_figure(width: float, height: float) -> Figure:
    """An empty figure of ``width`` x ``height`` inches on an Agg canvas, laid out tightly."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="tight")
    FigureCanvasAgg(fig)
    return fig


def save_png(fig: Figure, path: str | Path) -> None:
    """Save ``fig`` as a PNG at :data:`DPI` atomically."""
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=DPI)


def colors(n: int) -> list[Any]:
    """``n`` RGBA colours of the tab10 colour map, in its order (repeating after 10)."""
    from matplotlib import colormaps

    cmap = colormaps["tab10"]
    return [cmap(i % 10) for i in range(n)]


def plot_birdseye(
    path: str | Path,
    gt: np.ndarray | None,
    trajectories: Mapping[str, np.ndarray],
    title: str,
    styles: Mapping[str, Mapping[str, Any]] | None = None,
) -> None:
    """Bird's-eye view (x right, z forward, m) of (N, 4, 4) ground truth (None: none) and ``{label: (M, 4, 4)
    poses}`` as a PNG; ``styles``: per label, matplotlib line arguments replacing the defaults."""
    fig = new_figure(6.5, 6.5)
    ax = fig.add_subplot()
    if gt is not None:
        ax.plot(gt[:, 0, 3], gt[:, 2, 3], label="ground truth", **GROUND_TRUTH_STYLE)
    for (label, poses), color in zip(trajectories.items(), colors(len(trajectories)), strict=True):
        style = {"color": color, "lw": 1.2, **(styles or {}).get(label, {})}
        ax.plot(poses[:, 0, 3], poses[:, 2, 3], label=label, **style)
    start = gt if gt is not None else next(iter(trajectories.values()), None)
    if start is not None and len(start):
        ax.plot(start[0, 0, 3], start[0, 2, 3], "o", label="start", **START_STYLE)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("z (m)")
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    if ax.get_lines():
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0))
    save_png(fig, path)
