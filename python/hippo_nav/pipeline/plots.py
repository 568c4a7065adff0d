"""Figures of a run (matplotlib, Agg): the cognitive map, the neural state panels, firing-rate maps.

- `cognitive_map.png`: the corrected experience map (vertices, odometric links grey, loop links red) in
  the map frame (x forward along the initial heading, y left, metres), with the ground truth, the VO, the
  networks' own estimate (unwrapped place code and heading) and the corrected per-frame trajectory. All share the first frame as origin; nothing is aligned.
- `neural_state_NNNNNN.png` (one per chosen frame), like the paper's neural-representation figure:
  the HD-by-velocity ring (θ × ν), each grid module's conjunctive activity as a ν-grid of θ-planes (each
  small square is one velocity unit's (θx, θy) plane; the ν axes run across the squares), the three
  layer-II ("pure grid cell") patterns, and the CA3 place bump.
- `rate_maps.png`: firing-rate maps of chosen units (one per grid module and two place units): the mean
  activity of the unit in each spatial bin the agent visited, positions from the ground truth when there
  is one (as in a rat experiment), else from the corrected trajectory. The units shown are, among a
  regular sub-grid of every network, those whose activity varies most over the run.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def planar_xy(world_from_camera: np.ndarray) -> np.ndarray:
    """(n, 2) map-frame positions (forward = z, left = −x) of KITTI camera poses."""
    return np.stack([world_from_camera[:, 2, 3], -world_from_camera[:, 0, 3]], axis=1)


def plot_cognitive_map(result: Any, path: Path) -> Path:
    plt = _plt()
    export = result.map_export
    poses = export["poses"]
    links = export["links"].astype(int)
    is_loop = export["link_is_loop"].astype(bool)
    fig, ax = plt.subplots(figsize=(7.5, 6.5))
    if result.ground_truth is not None:
        gt = planar_xy(result.ground_truth)
        ax.plot(gt[:, 0], gt[:, 1], color="0.2", lw=2.5, alpha=0.35, label="ground truth")
    vo = planar_xy(result.vo_world_from_camera)
    ax.plot(vo[:, 0], vo[:, 1], color="tab:orange", lw=1, ls="--", label="VO alone")
    neural = planar_xy(result.neural_world_from_camera)
    ax.plot(neural[:, 0], neural[:, 1], color="tab:green", lw=0.8, ls=":", label="place code (neural)")
    corrected = planar_xy(result.corrected_world_from_camera)
    ax.plot(corrected[:, 0], corrected[:, 1], color="tab:blue", lw=1, label="corrected (per frame)")
    for (a, b), loop in zip(links, is_loop):
        if not loop:
            ax.plot(poses[[a, b], 0], poses[[a, b], 1], color="0.55", lw=0.6, zorder=1)
    for k, ((a, b), loop) in enumerate(zip(links, is_loop)):
        if loop:
            ax.plot(poses[[a, b], 0], poses[[a, b], 1], color="red", lw=1.5, zorder=3,
                    label="loop link" if k == int(np.argmax(is_loop)) else None)  # fmt: skip
    ax.scatter(poses[:, 0], poses[:, 1], s=6, color="black", zorder=2, label=f"{len(poses)} vertices")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m, initial heading)")
    ax.set_ylabel("y (m, left)")
    loops = int(is_loop.sum())
    ax.set_title(f"{result.name}: cognitive map, {loops} loop link{'s' * (loops != 1)}")
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def tile_conjunctive(activity: np.ndarray) -> np.ndarray:
    """(M, M, N, N) = (νy, νx, θy, θx) → an (M·N, M·N) image: row block νy, column block νx."""
    m_y, m_x, n_y, n_x = activity.shape
    return activity.transpose(0, 2, 1, 3).reshape(m_y * n_y, m_x * n_x)


def plot_neural_state(snapshot: dict[str, Any], path: Path, title: str) -> Path:
    plt = _plt()
    fig, axes = plt.subplots(2, 4, figsize=(16, 8))
    hd = snapshot["hd"]
    nu = snapshot["hd_nu_max"]
    ax = axes[0, 0]
    ax.imshow(hd, origin="lower", aspect="auto", cmap="viridis", extent=(0, 360, -nu, nu))
    ax.set_title("HD-by-velocity ring")
    ax.set_xlabel("θ (deg)")
    ax.set_ylabel("ν (angular velocity axis)")
    for m in range(3):
        ax = axes[0, m + 1]
        act = snapshot["grid"][m]
        k = snapshot["k"][m]
        if act is None:
            ax.text(0.5, 0.5, "lesioned", ha="center", va="center", transform=ax.transAxes)
        else:
            img = tile_conjunctive(act)
            ax.imshow(img, origin="lower", cmap="viridis", interpolation="nearest")
            n = act.shape[2]
            for b in range(1, act.shape[0]):
                ax.axhline(b * n - 0.5, color="white", lw=0.4)
                ax.axvline(b * n - 0.5, color="white", lw=0.4)
        ax.set_title(f"grid k={k}: conjunctive (νy, νx blocks of θ planes)", fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    for m in range(3):
        ax = axes[1, m]
        pattern = snapshot["layer2"][m]
        if pattern is None:
            ax.text(0.5, 0.5, "lesioned", ha="center", va="center", transform=ax.transAxes)
        else:
            ax.imshow(pattern, origin="lower", cmap="viridis", extent=(0, 2 * np.pi, 0, 2 * np.pi))
        ax.set_title(f"grid k={snapshot['k'][m]}: layer II")
        ax.set_xlabel("θx (rad)")
        ax.set_ylabel("θy (rad)")
    ax = axes[1, 3]
    ax.imshow(snapshot["place"], origin="lower", cmap="viridis", extent=(0, 2 * np.pi, 0, 2 * np.pi))
    ax.set_title("CA3 place torus")
    ax.set_xlabel("θx (rad)")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def rate_map(positions_m: np.ndarray, activity: np.ndarray, bin_m: float) -> tuple[np.ndarray, tuple]:
    """Mean activity per visited spatial bin (NaN where never visited) and its extent for imshow."""
    lo = positions_m.min(axis=0) - bin_m
    hi = positions_m.max(axis=0) + bin_m
    bins = [np.arange(lo[a], hi[a] + bin_m, bin_m) for a in range(2)]
    occupancy, _, _ = np.histogram2d(positions_m[:, 0], positions_m[:, 1], bins=bins)
    total, _, _ = np.histogram2d(positions_m[:, 0], positions_m[:, 1], bins=bins, weights=activity)
    with np.errstate(invalid="ignore", divide="ignore"):
        rates = np.where(occupancy > 0, total / occupancy, np.nan)
    return rates.T, (bins[0][0], bins[0][-1], bins[1][0], bins[1][-1])


def plot_rate_maps(result: Any, path: Path, bin_m: float) -> Path:
    plt = _plt()
    record = result.record
    track = result.ground_truth if result.ground_truth is not None else result.corrected_world_from_camera
    positions = planar_xy(track)[: len(record)]
    chosen: list[tuple[str, np.ndarray]] = []
    for name, rows in record.unit_activity.items():
        acts = np.stack(rows)  # (frames, units)
        # Units that fire in some places and not in others: the largest temporal spread.
        order = np.argsort(-acts.std(axis=0), kind="stable")
        picks = order[: 2 if name == "place" else 1]
        chosen += [(f"{name}, unit {int(u)}", acts[:, u]) for u in picks]
    cols = min(len(chosen), 3)
    rows = -(-len(chosen) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, 4.0 * rows), squeeze=False)
    for ax in axes.ravel()[len(chosen) :]:
        ax.set_axis_off()
    for ax, (label, activity) in zip(axes.ravel(), chosen):
        rates, extent = rate_map(positions, activity.astype(np.float64), bin_m)
        ax.imshow(rates, origin="lower", extent=extent, cmap="jet", interpolation="nearest")
        ax.plot(positions[:, 0], positions[:, 1], color="white", lw=0.4, alpha=0.6)
        ax.set_title(label, fontsize=9)
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    source = "ground truth" if result.ground_truth is not None else "corrected trajectory"
    fig.suptitle(f"{result.name}: firing-rate maps (positions from the {source})")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def write_run_figures(result: Any, out: Path, rate_map_bin_m: float = 4.0) -> list[Path]:
    """Every figure of a run into `out`; returns their paths."""
    paths = [plot_cognitive_map(result, out / "cognitive_map.png")]
    for position, snapshot in sorted(result.record.snapshots.items()):
        frame = snapshot["frame_index"]
        paths.append(
            plot_neural_state(
                snapshot,
                out / f"neural_state_{frame:06d}.png",
                f"{result.name}: neural state at frame {frame} (run position {position})",
            )
        )
    if len(result.record) >= 2:
        paths.append(plot_rate_maps(result, out / "rate_maps.png", rate_map_bin_m))
    return paths
