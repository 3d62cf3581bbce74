"""`explain`: every view of one checkpoint, as PNGs and an index.html that shows them together.

    explain("runs/demo/csc", "runs/explain", task="key")        # trajectories generated
    explain("runs/demo/csc", "runs/explain", bag="bags/run1")   # a recording's episodes

Views: hidden-state embeddings (models with an LSTM), reward maps and probe trajectories
(navigation tasks and Lunar Lander), and per-episode views (with a bag: path, served reward,
oracle reward).
"""

from __future__ import annotations

import html
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..mil import load_checkpoint
from ..tasks import task_info
from . import plots
from .embeddings import hidden_embedding
from .episode_view import read_episodes
from .probes import probe_states
from .reward_maps import context_prefixes, learnt_reward_map, oracle_reward_map
from .traces import model_traces, oracle_traces, pixel_inputs


@dataclass
class Figure:
    section: str
    path: Path
    caption: str


def _trajectories(task: str, bag: str | Path | None, n: int, seed: int, view_task: str):
    """(states (N, T, d), lengths (N,), description) of `view_task` (`task`'s, or for a pixel task
    its state task's: the positions behind the images) from a bag's complete episodes of `task`
    or generated."""
    if bag is not None:
        episodes = [e for e in read_episodes(bag).values() if e.task == task][:n]
        if not episodes:
            raise ValueError(f"{bag}: no complete episode of task {task!r}")
        if view_task != task and any(e.privileged is None for e in episodes):
            raise ValueError(f"{bag}: its {task} episodes have no privileged state (the positions behind the images)")
        seen = [e.states if view_task == task else e.privileged for e in episodes]
        horizon = max(len(x) for x in seen)
        states = np.zeros((len(seen), horizon, seen[0].shape[1]), np.float32)
        for i, x in enumerate(seen):
            states[i, :len(x)] = x
        return states, np.array([len(x) for x in seen]), f"{len(episodes)} episodes of {bag}"
    from ..datasets import generate_screened

    ds = generate_screened(view_task, n, seed=seed)
    return ds.states, ds.lengths, f"{len(ds)} screened {task} trajectories (data seed {seed})"


def _views_of(task: str) -> tuple:
    """(the task whose states the views draw, what the model reads of them): (task, None) for a
    vector state; a pixel navigation task's state task and its renderer (`pixel_inputs`); a
    ValueError (one line) for any other image state."""
    info = task_info(task)
    if not info.image_shape:
        return task, None
    if not info.pixels_of:
        raise ValueError(f"task {task!r} has an image state: the views (maps, probes, embeddings against the "
                         f"oracle's hidden state) are drawn from the positions behind the images, which only the "
                         f"pixel navigation tasks (<t>_pixels) define")
    return info.pixels_of, pixel_inputs(task)


def explain(checkpoint: str | Path, out: str | Path, bag: str | Path | None = None,
            task: str | None = None, n: int = 300, seed: int = 1, episodes: int = 3,
            grid_size: int = 41) -> list:
    """Write every view of `checkpoint` into `out` (PNGs + index.html); returns the Figures.

    task defaults to the checkpoint's; n trajectories for the embeddings (generated with data
    seed `seed`, or the first n complete episodes of `bag`); `episodes` per-episode views (bag)."""
    start = time.perf_counter()
    model, record = load_checkpoint(checkpoint)
    task = task or record.task
    if record.task != task:
        raise ValueError(f"the checkpoint was trained on {record.task!r}, not {task!r}")
    view_task, inputs = _views_of(task)  # a pixel task: drawn at the positions, the model reads images
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    name = Path(checkpoint).with_suffix("").name
    arch = model.config.architecture
    members = model.members
    figures: list = []
    has_memory = model.hidden_size > 0  # an LSTM's h' or a transformer's z

    states, lengths, described = _trajectories(task, bag, n, seed, view_task)
    if has_memory:
        emb = hidden_embedding(model, view_task, states, lengths, inputs)
        figures.append(Figure("Hidden-state embedding", plots.embedding_figure(
            emb, view_task, f"{name} ({arch}) on {task}", out / "hidden_embedding.png"),
            f"h'_(t+1) of {described}; {emb.projection}."))

    maps = [(c.label, learnt_reward_map(model, prefix, grid_size, view_task, inputs),
             oracle_reward_map(view_task, prefix, grid_size))
            for c, prefix in context_prefixes(view_task)]
    if maps:
        note = task_info(view_task).map_note
        figures.append(Figure("Reward maps", plots.reward_map_figure(view_task, maps, out / "reward_maps.png"),
                              "Reward for one step at each (x, y) after a context (a probe cut at "
                              "step t); learnt above, oracle below." + (f" {note}" if note else "")
                              + (" The model read the image of each position." if inputs else "")))

    for probe, path in probe_states(view_task):
        rewards, hidden = model_traces(model, path, inputs=inputs)
        oracle_r, oracle_h = oracle_traces(view_task, path)
        file = out / f"probe_{probe.name.replace(' ', '_').replace('-', '_')}.png"
        figures.append(Figure("Probe trajectories", plots.trace_figure(
            view_task, f"probe '{probe.name}': {probe.description}", path,
            {"learnt": rewards, "oracle": oracle_r}, hidden, oracle_h, file),
            f"{probe.name}: {probe.description}."))

    if bag is not None:
        for (source, episode), rec in list(read_episodes(bag).items())[:episodes]:
            drawn_task = task_info(rec.task).pixels_of or rec.task  # a pixel task's episode: drawn at its positions
            if drawn_task != rec.task and rec.privileged is None:
                continue  # a pixel episode recorded without its positions: nothing to draw it on
            path = rec.states if drawn_task == rec.task else rec.privileged
            learnt, hidden = model_traces(model, rec.states) if rec.task == task else (None, None)
            oracle_h = oracle_traces(rec.task, path)[1]
            where = f"episode {episode}" + (f" of {source}" if source.strip("/") else "")
            rewards = {"served" + (f" ({', '.join(rec.served_by)})" if rec.served_by else ""): rec.served,
                       f"oracle ({'recorded' if rec.oracle_recorded else 'computed'})": rec.oracle,
                       f"this model ({name})": learnt}
            file = out / f"episode_{source.strip('/').replace('/', '_') or 'root'}_{episode}.png"
            figures.append(Figure("Recorded episodes", plots.trace_figure(
                drawn_task, f"{rec.task}, {where}", path, rewards, hidden, oracle_h, file),
                f"{where}: {len(rec.states)} steps; served reward "
                f"{'recorded' if rec.served is not None else 'not recorded'}."))

    _write_index(out, f"{name}: {arch}, {members} member(s), task {task}", figures,
                 time.perf_counter() - start)
    return figures


def _write_index(out: Path, title: str, figures: list, seconds: float) -> Path:
    e = html.escape
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{e(title)}</title>",
             "<style>body{font-family:sans-serif;max-width:1400px;margin:auto}"
             "figure{display:inline-block;margin:8px;vertical-align:top}"
             "img{max-width:100%;border:1px solid #ccc}figcaption{font-size:13px;max-width:900px}"
             "</style></head><body>", f"<h1>{e(title)}</h1>",
             f"<p>Written by <code>nmrm explain</code> in {seconds:.1f} s.</p>"]
    section = None
    for f in figures:
        if f.section != section:
            section = f.section
            parts.append(f"<h2>{e(section)}</h2>")
        parts.append(f"<figure><img src='{e(f.path.name, quote=True)}' alt='{e(f.caption, quote=True)}'>"
                     f"<figcaption>{e(f.caption)}</figcaption></figure>")
    parts.append("</body></html>")
    path = out / "index.html"
    path.write_text("\n".join(parts))
    return path
