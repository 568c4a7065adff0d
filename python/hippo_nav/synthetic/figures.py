"""Figures of the synthetic street: one place at each appearance level (docs/render.md).

Drawn on a `matplotlib.figure.Figure` (Agg canvas), so no global pyplot state is touched.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from hippo_nav.io.atomic import write_image
from hippo_nav.io.errors import DatasetError
from hippo_nav.synthetic.appearance import (
    APPEARANCE_LEVELS,
    AppearanceModel,
    lane_offsets_m,
    shift_sideways,
    shutter_motion,
)
from hippo_nav.synthetic.render import (
    KITTI_FOCAL_RATIO,
    check_image_size,
    check_render_options,
    stereo_projections,
)
from hippo_nav.synthetic.trajectories import loop_trajectory
from hippo_nav.synthetic.world import StreetWorld

FIGURE_FRAME = 120
"""The place shown: frame 120 of `loop_trajectory(200)`, on the loop's last long straight, looking along it."""


def appearance_images(
    image_size_px: tuple[int, int] = (320, 96), seed: int = 0, frame: int = FIGURE_FRAME
) -> dict[tuple[str, int], np.ndarray]:
    """The left image of one place of the demo loop at every level, on pass 0 and pass 1: {(level, pass): image}.

    Pass 1 is rendered as a revisit is: every object in its pass-1 state, the pass-1 light and, where the
    level has one, the pass-1 lane offset."""
    image_size_px = check_image_size(image_size_px)
    seed = check_render_options(seed, 1, False)[0]
    poses = loop_trajectory(200)
    if isinstance(frame, bool) or not isinstance(frame, (int, np.integer)) or not 0 <= frame < len(poses) - 1:
        raise DatasetError(f"frame {frame!r}: give a frame of the demo loop, 0 to {len(poses) - 2}")
    world = StreetWorld(poses[:, :3, 3], seed=seed)
    K = stereo_projections(image_size_px, 0.537, KITTI_FOCAL_RATIO)[0][:, :3]
    images = {}
    for level in APPEARANCE_LEVELS:
        model = AppearanceModel(world, level, seed)
        for pass_index in (0, 1):
            pose = shift_sideways(
                poses[frame : frame + 1], lane_offsets_m(np.array([pass_index]), level, seed)
            )[0]
            images[level, pass_index] = model.render(
                pose,
                K,
                image_size_px,
                model.at_pass(pass_index),
                camera_from_next=shutter_motion(poses, frame),
                noise_rng=np.random.default_rng([seed, frame, pass_index]),
            )
    return images


def appearance_figure(path: str | Path, image_size_px: tuple[int, int] = (320, 96), seed: int = 0) -> Path:
    """One place at each appearance level (rows), pass 0 and pass 1 (columns), as a PNG at `path`."""
    image_size_px = check_image_size(image_size_px)
    images = appearance_images(image_size_px, seed)
    width, height = image_size_px
    figure = Figure(figsize=(2 * width / 100 + 0.5, len(APPEARANCE_LEVELS) * (height / 100 + 0.3) + 0.2))
    axes = figure.subplots(len(APPEARANCE_LEVELS), 2, squeeze=False)
    figure.subplots_adjust(left=0.06, right=0.99, top=0.93, bottom=0.01, wspace=0.02, hspace=0.25)
    for row, level in enumerate(APPEARANCE_LEVELS):
        for column in (0, 1):
            ax = axes[row, column]
            ax.imshow(images[level, column], cmap="gray", vmin=0, vmax=255, interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(f"{level}, pass {column}", fontsize=8, loc="left")
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    canvas = FigureCanvasAgg(figure)
    canvas.draw()
    # Stored as an 8-bit gray PNG: a quarter of matplotlib's RGBA (the figure is gray anyway).
    gray = cv2.cvtColor(np.asarray(canvas.buffer_rgba()), cv2.COLOR_RGBA2GRAY)
    return write_image(out, gray, [cv2.IMWRITE_PNG_COMPRESSION, 9])
