"""Matplotlib figures of the interpretability views; each function writes one PNG and returns
its path. The map drawing (`draw_zones`: the zones of the task's TaskInfo) is shared by all of them."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402

from .embeddings import ORACLE_VARIABLE, Embedding  # noqa: E402
from ..tasks import task_info  # noqa: E402
from .reward_maps import extent  # noqa: E402



def draw_zones(ax, task: str) -> None:
    """The task's map (its TaskInfo's arena, e.g. a navigation task's unit square or Lunar
    Lander's screen) with the zones its TaskInfo names."""
    info = task_info(task)
    x0, x1, y0, y1 = extent(task)
    for z in info.zones:
        if z.style == "bar":
            ax.plot([z.x_min, z.x_max], [z.y_min, z.y_min], color=z.colour, lw=4, label=z.label,
                    solid_capstyle="butt")
        else:
            ax.add_patch(Rectangle((z.x_min, z.y_min), z.x_max - z.x_min, z.y_max - z.y_min, fill=False,
                                   edgecolor=z.colour, lw=1.5, label=z.label,
                                   ls="--" if z.style == "dashed" else "-"))
    # a bar on the map's bottom edge (a pad on the ground) gets room to show
    below = 0.05 if any(z.style == "bar" and z.y_min <= y0 for z in info.zones) else 0.0
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0 - below, y1)
    ax.set_aspect("equal")
    ax.set_xlabel("x")
    ax.set_ylabel("y")


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def embedding_figure(emb: Embedding, task: str, title: str, path: Path) -> Path:
    """Two scatter panels of the same points: coloured by the oracle's hidden variable, by t."""
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.3))
    for ax, values, name in ((axes[0], emb.oracle, ORACLE_VARIABLE.get(task, "oracle hidden")),
                             (axes[1], emb.time, "time step t")):
        sc = ax.scatter(emb.points[:, 0], emb.points[:, 1], c=values, s=3, cmap="viridis", alpha=0.6)
        fig.colorbar(sc, ax=ax, label=name)
        ax.set_title(f"coloured by {name}", fontsize=9)
        pc = emb.projection != "hidden state"
        ax.set_xlabel("PC 1" if pc else "h'[0]")
        ax.set_ylabel("PC 2" if pc else "h'[1]")
    note = emb.projection
    if emb.explained is not None:
        note += f" (explains {emb.explained[0]:.0%} + {emb.explained[1]:.0%} of the variance)"
    fig.suptitle(f"{title}: {note}", fontsize=10)
    return _save(fig, path)


def reward_map_figure(task: str, maps: list, path: Path) -> Path:
    """maps: [(label, learnt (n, n), oracle (n, n))]; a column per context, learnt above oracle,
    one colour scale for all."""
    cols = len(maps)
    fig, axes = plt.subplots(2, cols, figsize=(3.3 * cols, 6.4), squeeze=False)
    values = np.concatenate([np.ravel(m) for _, a, b in maps for m in (a, b)])
    lo, hi = float(values.min()), float(values.max())
    if lo == hi:
        lo, hi = lo - 1, hi + 1
    for j, (label, learnt, oracle) in enumerate(maps):
        for i, (name, m) in enumerate((("learnt", learnt), ("oracle", oracle))):
            ax = axes[i, j]
            im = ax.imshow(m, origin="lower", extent=extent(task), vmin=lo, vmax=hi, cmap="coolwarm")
            draw_zones(ax, task)
            ax.set_title(f"{name}: {label}", fontsize=9)
    fig.colorbar(im, ax=axes.ravel().tolist(), shrink=0.8, label="reward for one step at (x, y)")
    fig.suptitle(f"{task}: reward over the {task_info(task).map_name} "
                 "after a context", fontsize=10)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def trace_figure(task: str, title: str, states: np.ndarray, rewards: dict, hidden: np.ndarray | None,
                 oracle_hidden: np.ndarray | None, path: Path) -> Path:
    """A trajectory: its path over the arena, the rewards per step (name -> (T,)), and the served
    state per step (hidden (T, 2k): [h', tanh c'], as `model_traces` gives it) beside the oracle's."""
    panels = 3 if hidden is not None and hidden.shape[-1] > 0 else 2
    fig, axes = plt.subplots(1, panels, figsize=(4.4 * panels, 4))
    ax = axes[0]
    if task_info(task).arena is not None:
        draw_zones(ax, task)
        ax.legend(loc="lower right", fontsize=6)
    ax.plot(states[:, 0], states[:, 1], "-", color="black", lw=0.8)
    sc = ax.scatter(states[:, 0], states[:, 1], c=np.arange(len(states)), s=8, cmap="viridis", zorder=3)
    fig.colorbar(sc, ax=ax, label="t")
    ax.set_title("path", fontsize=9)
    ax = axes[1]
    for (name, r), style in zip(rewards.items(), ("-", "--", ":")):
        if r is not None:
            ax.plot(r, style, label=f"{name} (return {np.sum(r):.2f})")
    ax.set_xlabel("t")
    ax.set_ylabel("reward")
    ax.legend(fontsize=7)
    ax.set_title("reward per step", fontsize=9)
    if panels == 3:
        ax = axes[2]
        k = hidden.shape[1] // 2
        shown = list(range(min(k, 4))) + list(range(k, k + min(k, 4)))  # up to 4 of h' and of c'
        for j in shown:
            ax.plot(hidden[:, j], "-" if j < k else ":",
                    label=f"learnt h'[{j}]" if j < k else f"learnt tanh c'[{j - k}]")
        if oracle_hidden is not None:
            ax2 = ax.twinx()
            ax2.plot(oracle_hidden[:, 0], "k--", lw=1, label="oracle h[0]")
            ax2.set_ylabel("oracle hidden", fontsize=8)
            ax2.legend(loc="lower right", fontsize=7)
        ax.set_xlabel("t")
        ax.legend(loc="upper left", fontsize=7)
        ax.set_title("served state [h', tanh c']", fontsize=9)
    fig.suptitle(title, fontsize=10)
    return _save(fig, path)
