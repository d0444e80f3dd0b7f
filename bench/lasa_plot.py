"""Plots of the LASA benchmark written by `ciflow lasa` (PNG).

Usage: python lasa_plot.py OUT_DIR

Reads OUT_DIR/plots/<shape>.json (demonstrations, noise-free rollouts of the flow and of
the behaviour-cloning baseline, and each model's desired velocity on a grid: J_f(z) v(z)
for the flow, the network's output for the baseline) and writes
- OUT_DIR/plots/<shape>.png: the flow (left) and the baseline (right), each with its
  streamlines, the demonstrations (grey, dashed) and its rollouts from their starts;
- OUT_DIR/lasa.png: every shape in a grid, flow streamlines behind the demonstrations,
  flow rollouts (blue) and baseline rollouts (red).
"""

import json
import math
import pathlib
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

MODELS = (("flow", "C-IFlow (stable)", "tab:blue"), ("baseline", "MLP BC", "tab:red"))


def as_array(values):
    """JSON numbers to floats; `null` (a non-finite value) becomes NaN."""
    return np.array([[math.nan if v is None else v for v in row] for row in values], float)


def draw_field(ax, field, color="0.75"):
    x, y = np.array(field["x"]), np.array(field["y"])
    u, v = as_array(field["u"]), as_array(field["v"])
    finite = np.isfinite(u) & np.isfinite(v)
    u, v = np.where(finite, u, 0.0), np.where(finite, v, 0.0)
    speed = np.hypot(u, v)
    if speed.max() > 0:
        ax.streamplot(x, y, u, v, color=color, linewidth=0.6, density=1.0, arrowsize=0.6)
    ax.set_xlim(x[0], x[-1])
    ax.set_ylim(y[0], y[-1])


def draw_paths(ax, paths, style, **kwargs):
    for path in paths:
        p = np.array(path, float).reshape(-1, 2)
        if len(p):
            ax.plot(p[:, 0], p[:, 1], style, **kwargs)


def draw_demos(ax, shape):
    draw_paths(ax, shape["demos"], "--", color="0.35", lw=1.0)
    starts = np.array([d[0] for d in shape["demos"]])
    ax.plot(starts[:, 0], starts[:, 1], "ko", ms=3)
    ax.plot(*shape["goal"], "g*", ms=10)


def plot_shape(shape, path):
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.8))
    for ax, (key, title, color) in zip(axes, MODELS):
        draw_field(ax, shape[key]["field"])
        draw_demos(ax, shape)
        draw_paths(ax, shape[key]["rollouts"], "-", color=color, lw=1.5)
        ax.set_title(f"{shape['shape']}: {title}")
        ax.set_aspect("equal")
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_overview(shapes, path):
    columns = min(6, len(shapes))
    rows = math.ceil(len(shapes) / columns)
    fig, axes = plt.subplots(rows, columns, figsize=(3 * columns, 3 * rows), squeeze=False)
    for ax in axes.flat[len(shapes):]:
        ax.axis("off")
    for ax, shape in zip(axes.flat, shapes):
        draw_field(ax, shape["flow"]["field"])
        draw_demos(ax, shape)
        for key, _, color in MODELS:
            draw_paths(ax, shape[key]["rollouts"], "-", color=color, lw=1.0)
        ax.set_title(shape["shape"], fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_aspect("equal")
    handles = [plt.Line2D([], [], color=c, label=t) for _, t, c in MODELS]
    handles.append(plt.Line2D([], [], color="0.35", ls="--", label="demonstrations"))
    fig.legend(handles=handles, loc="lower center", ncol=3, frameon=False)
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main():
    out = pathlib.Path(sys.argv[1])
    files = sorted((out / "plots").glob("*.json"))
    if not files:
        sys.exit(f"no plot data in {out / 'plots'}")
    shapes = [json.loads(f.read_text()) for f in files]
    for shape, f in zip(shapes, files):
        plot_shape(shape, f.with_suffix(".png"))
    plot_overview(shapes, out / "lasa.png")


if __name__ == "__main__":
    main()
