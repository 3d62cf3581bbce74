"""`nmrm train|evaluate|calibrate|explain|check`: a reward model's life on the command line."""

from __future__ import annotations

from pathlib import Path

import typer

from .app import app
from .common import (ORACLE_HELP, writable_dir, writable_file, load_bags, load_or_generate, metrics_line)


@app.command()
def train(
    task: str = typer.Option(None, help="task or toy dataset to generate data for (if no --data)"),
    data: Path = typer.Option(None, help="a dataset .npz (from `nmrm dataset ...`)"),
    bag: list[Path] = typer.Option(None, help="bag(s) of recorded episodes (repeatable)"),
    labeller: str = typer.Option(None, help="with --bag: whose labels to use if several labelled"),
    arch: str = typer.Option("csc_lstm", help="instance_nn | embedding_lstm | instance_lstm | csc_lstm | transformer"),
    out: Path = typer.Option(Path("runs/model"), help="checkpoint path (writes OUT.pt and OUT.json)",
                             callback=writable_file),
    n: int = typer.Option(5000, min=1, help="trajectories to generate (without --data)"),
    data_seed: int = typer.Option(0, min=0, help="seed of the generated data"),
    seed: int = typer.Option(0, min=0, help="seed of the weight initialisation and batch order"),
    split_seed: int = typer.Option(0, min=0, help="seed of the 80/10/10 train/val/test split"),
    epochs: int = typer.Option(None, min=1, help="override max_epochs"),
    lr: float = typer.Option(None, help="override the learning rate"),
    batch_size: int = typer.Option(None, min=1, help="override the batch size"),
    config: Path = typer.Option(None, help="training config YAML (default config/mil_training.yaml)",
                                exists=True, dir_okay=False, readable=True),
    ensemble: int = typer.Option(None, min=1, help="train K models as one ensemble in one pass (seeds SEED..SEED+K-1; "
                                 "served as their mean reward); default: the task's `members` in the config"),
    split_mode: str = typer.Option("shared", help="ensemble splits: shared | bootstrap | per_member"),
    keep_members: str = typer.Option(None, help="of an ensemble's members, which are served: fitted (all but one "
                                     "that did not fit: validation 1 - R^2 over 0.01 and over 4x the best member's) "
                                     "| all | best (only the best on validation); default: the task's config"),
    redraws: int = typer.Option(None, min=0, help="when no member explains 75% of the validation returns' variance "
                                "(stuck on the Markovian plateau) and none stopped at the epoch limit, draw K new "
                                "members up to this many times and keep the best draw (0: never); default: the "
                                "task's config"),
    label_swap: float = typer.Option(None, min=0.0, max=1.0, help="label noise: swap this fraction of the training and "
                                     "validation labels between trajectories (paper Sec. 5.2)"),
    reward_l1: float = typer.Option(None, min=0.0, help="override the weight of the L1 sparsity prior on "
                                    "per-step rewards (config/mil_training.yaml; 0: off; not used with "
                                    "--feedback preferences, which leaves the rewards' scale free)"),
    prefix_fraction: float = typer.Option(None, min=0.0, max=1.0, help="cut this fraction of the training and "
                                          "validation episodes at a random step, labelled with the return "
                                          "earned by then (needs the oracle's per-step rewards; default: the "
                                          "task's config)"),
    output_activation: str = typer.Option(None, help="the head's output activation: none | leaky_relu (the "
                                          "paper's, slope 1e-6) | softplus; default: the task's config"),
    feedback: str = typer.Option(None, help="what to learn from: returns (the MSE of episode returns) | "
                                 "preferences (a Bradley-Terry loss on pairwise comparisons) | both; default "
                                 "returns"),
    fe_sizes: str = typer.Option(None, help="feature-extractor layer widths, e.g. 64,32,32; default: the "
                                 "task's config, else the paper's for the task's family"),
    head_sizes: str = typer.Option(None, help="head hidden-layer widths, e.g. 32,16 ('' for none); default: "
                                   "as --fe-sizes"),
) -> None:
    """Train a MIL reward model or an ensemble (early stopping on the validation loss) and
    evaluate it on the test split."""
    from ..mil import ARCHITECTURES, load_train_config
    from ..mil.pipeline import SPLIT_MODES, fit

    if arch not in ARCHITECTURES:
        raise typer.BadParameter(f"unknown architecture {arch!r}; known: {', '.join(ARCHITECTURES)}")
    if split_mode not in SPLIT_MODES:
        raise typer.BadParameter(f"--split-mode must be one of {', '.join(SPLIT_MODES)}, got {split_mode!r}")
    settings = dict(max_epochs=epochs, lr=lr, batch_size=batch_size, seed=seed, label_swap=label_swap,
                    reward_l1=reward_l1, feedback=feedback, output_activation=output_activation,
                    fe_sizes=fe_sizes, head_sizes=head_sizes, prefix_fraction=prefix_fraction,
                    keep_members=keep_members, redraws=redraws)
    if task:  # the settings are checked before any data is loaded or generated
        load_train_config(task, config, **settings)
    if bag:
        ds, source = load_bags(bag, task, labeller)
    else:
        ds, source = load_or_generate(data, task, n, data_seed)
    cfg = load_train_config(ds.task, config, **settings)
    if len(ds) < 10:
        raise typer.BadParameter(f"{len(ds)} trajectories cannot be split 80/10/10 into train, validation "
                                 f"and test sets: give at least 10 (the paper: 5000)")
    if len(ds) < 100:
        typer.echo(f"warning: only {len(ds)} trajectories; the validation and test sets have about "
                   f"{len(ds) // 10} each, so the figures below are noise", err=True)
    compared = 0 if ds.preferences is None else len(ds.preferences)
    typer.echo(f"training {arch} on {ds.task}" + (f" from {cfg.feedback}" if cfg.feedback != "returns" else "")
               + f": {len(ds)} trajectories"
               + (f", {compared} comparisons" if compared else "") + f" ({source}), "
               f"lr {cfg.lr}, batch {cfg.batch_size}, max {cfg.max_epochs} epochs, seed {seed}"
               + (f", {cfg.label_swap:g} of the labels swapped" if cfg.label_swap else ""))
    if cfg.feedback == "preferences" and reward_l1:
        typer.echo(f"note: --reward-l1 {reward_l1:g} is not used with --feedback preferences (comparisons leave "
                   f"the rewards' scale free: the prior would shrink it towards 0)", err=True)
    members = cfg.members if ensemble is None else ensemble
    run = fit(ds, arch, cfg, members, split_seed=split_seed, split_mode=split_mode,
                     out=out, data_source=source)
    _print_run(run, cfg)


def _print_run(run, cfg) -> None:
    """What `nmrm train` prints of a run: the single model's line, or one per member and the mean;
    and which candidates were left out (keep_members best / fitted)."""
    t = run.train
    kept = run.kept or list(range(run.model.members))  # the members' entries in the training record
    losses = ", ".join(f"{v:.4g}" for v in t.best_val_loss)
    if run.chosen is not None:
        typer.echo(f"best of {len(t.best_val_loss)} candidates on validation (losses {losses}): "
                   f"candidate {run.chosen}, seed {run.seeds[0]}")
    _print_draws(run.meta.metrics.get("draws"))
    if run.model.members == 1:
        c = kept[0]
        typer.echo(f"best epoch {t.best_epochs[c]}/{t.epochs_run} in {t.seconds:.1f} s; "
                   f"test {metrics_line(run.test_metrics)}")
        if t.still_improving[c]:
            typer.echo(f"note: still improving at the epoch limit ({cfg.max_epochs}); more epochs may help")
        _print_left_out(run, kept)
    else:
        typer.echo(f"{len(t.best_val_loss)} members in one pass: {t.epochs_run} epochs in {t.seconds:.1f} s")
        for m, test in enumerate(run.member_test):
            c = kept[m]
            flag = ", still improving at the limit" if t.still_improving[c] else ""
            typer.echo(f"  member {c} (seed {run.seeds[m]}, split {run.split_seeds[m]}): best epoch "
                       f"{t.best_epochs[c]}; test {metrics_line(test)}{flag}")
        _print_left_out(run, kept)
        if run.test_metrics is not None:
            m = run.test_metrics
            typer.echo(f"ensemble mean: test {metrics_line(m)}, mean return std {m['return_std']:.4f}")
        typer.echo(f"serving member (hidden state): {kept[int(run.model.serving_member)]}")
    _print_fit(run.meta.metrics.get("val_unexplained_variance"))
    units = run.meta.metrics.get("step_units") or {}
    if "largest_step_reward" in units:
        typer.echo(f"rewards in units of the model's largest step on the dataset's episodes (comparisons leave "
                   f"the scale free; it was {units['largest_step_reward']:.3g}); nmrm calibrate gives them the "
                   f"units of return labels")
    elif "skipped" in units:
        typer.echo(f"rewards on the scale training reached (comparisons leave it free): {units['skipped']}")
    typer.echo(f"checkpoint: {run.checkpoint} (+ .json)")


def _print_draws(draws: list | None) -> None:
    """redraws: each draw of members that was trained, and which was kept (nothing for one draw)."""
    if not draws:
        return
    from ..mil.fitted import POORLY_FITTED

    for d, draw in enumerate(draws, 1):
        recorded = draw.get("patience")  # [patience, plateau patience], recorded since redraw_patience
        patience = f", patience {recorded[0]} (plateau {recorded[1]})" if recorded else ""
        typer.echo(f"draw {d} (seeds {', '.join(map(str, draw['seeds']))}{patience}): {draw['epochs_run']} epochs in "
                   f"{draw['seconds']:.1f} s, best member's validation 1 - R^2 {min(draw['unexplained']):.3g}"
                   f"{' (kept)' if draw['kept'] else ''}")
    typer.echo(f"(new members are drawn, each draw with more patience, while none explains {1 - POORLY_FITTED:.0%} "
               f"of the validation returns' variance, up to the config's redraws; {sum(d['seconds'] for d in draws):.1f} s in all; "
               f"the lines below are the kept draw's)")


def _print_fit(unexplained: float | None) -> None:
    """How much of the validation returns' variance the served model explains; a warning with the
    next step when it is too little (`fitted.poorly_fitted`)."""
    from ..mil.fitted import POORLY_FITTED, poorly_fitted

    if unexplained is None:
        return
    share = f"the model explains {max(0.0, 1.0 - unexplained):.1%} of the variance of the validation returns"
    if not poorly_fitted(unexplained):
        typer.echo(share)
        return
    typer.echo(f"warning: {share} (under {1 - POORLY_FITTED:.0%}): it may have stayed on the Markovian plateau "
               f"(paying the present state only; `nmrm check` tells), or the labels are noisy; train again with "
               f"another --seed, more members (--ensemble) or more episodes")


def _print_left_out(run, kept: list) -> None:
    """keep_members fitted: the members left out of the served mean, and why (nothing otherwise)."""
    u = run.meta.metrics.get("candidate_unexplained_variance")
    if run.kept is None or run.chosen is not None or u is None:
        return
    from ..mil.fitted import FITTED_FLOOR, FITTED_RATIO

    out = ", ".join(f"member {m} (seed {run.meta.ensemble.candidate_seeds[m]}, 1 - R^2 {u[m]:.3g})"
                    for m in range(len(u)) if m not in kept)
    typer.echo(f"left out of the served mean, as it did not fit: {out}; the rule: validation 1 - R^2 of "
               f"the returns over {FITTED_FLOOR:g} and over {FITTED_RATIO:g}x the best member's ({min(u):.3g})")


@app.command()
def evaluate(
    checkpoint: Path = typer.Option(..., help="checkpoint path (.pt or .json or the stem)"),
    data: Path = typer.Option(None, help="dataset .npz (default: regenerate the training data)"),
    bag: list[Path] = typer.Option(None, help="bag(s) of recorded episodes with OracleStep ground truth"),
    labeller: str = typer.Option(None, help="with --bag: whose labels to use if several labelled"),
    split: str = typer.Option("test", help="test | val | train | all (of the dataset)"),
) -> None:
    """Test-split return MSE and reward MSE of a checkpoint (the paper's table metrics)."""
    from ..mil import evaluate as evaluate_model, load_checkpoint
    from ..mil.data import split_indices

    model, meta = load_checkpoint(checkpoint)
    if bag:
        ds, _ = load_bags(bag, meta.task, labeller)
        if not ds.meta.get("oracle_ground_truth"):
            typer.echo("note: not every episode has OracleStep ground truth; reward MSE is against zeros there")
    elif data is None:
        source = meta.data.source
        if not source.regenerable:
            raise typer.BadParameter(f"checkpoint data source {str(source)!r} cannot be regenerated; give --data")
        if source.kind == "bags":
            ds, _ = load_bags(source.paths, meta.task, None)
        elif source.kind == "file":
            ds, _ = load_or_generate(Path(source.paths[0]), None, 0, 0)
        else:
            ds, _ = load_or_generate(None, source.task, source.n, source.seed)
    else:
        ds, _ = load_or_generate(data, None, 0, 0)
    if ds.state_size != model.config.input_size:
        raise typer.BadParameter(f"dataset states have size {ds.state_size}, the model takes "
                                 f"{model.config.input_size}")
    if split != "all":
        names = ("train", "val", "test")
        if split not in names:
            raise typer.BadParameter(f"--split must be one of {names + ('all',)}")
        ds = ds.subset(split_indices(len(ds), meta.split_seed or 0)[names.index(split)])
    m = evaluate_model(model, ds)
    what = f"{model.members}-member ensemble of " if model.members > 1 else ""
    typer.echo(f"{what}{model.config.architecture} on {ds.task} ({split}): {metrics_line(m)} "
               f"(of the reward MSE, the mean error per step index: {m['reward_mse_time_profile']:.5f})")
    if meta.train_config.get("feedback") == "preferences":
        typer.echo("note: trained on preferences, which fix returns only up to an offset and a scale: "
                   "judge it by the preference accuracy and the reward correlation, not the MSEs")


@app.command()
def calibrate(
    checkpoint: Path = typer.Option(..., help="checkpoint path (.pt or .json or the stem), e.g. a model of comparisons"),
    out: Path = typer.Option(..., help="checkpoint path of the calibrated model (writes OUT.pt and OUT.json)",
                             callback=writable_file),
    data: Path = typer.Option(None, help="dataset .npz whose return-labelled episodes calibrate"),
    bag: list[Path] = typer.Option(None, help="bag(s) whose return labels calibrate (repeatable)"),
    labeller: str = typer.Option(None, help="with --bag: whose labels to use if several labelled"),
    labels: int = typer.Option(None, min=2, help="use this many return-labelled episodes (a seeded subset; "
                               "default all)"),
    seed: int = typer.Option(0, min=0, help="seed of the --labels subset"),
) -> None:
    """Give a model of comparisons the units of returns: fit each member's predicted returns to a few
    return labels (R' = gain R + bias L) and write a copy whose rewards are (r' - bias) / gain."""
    import numpy as np

    from ..mil import Run, evaluate as evaluate_model
    from ..mil.calibration import calibrate as calibrate_model, check_calibratable, fit_calibration
    from ..mil.checkpoint import checkpoint_paths

    if (data is None) == (not bag):
        raise typer.BadParameter("give the return labels as --data FILE or --bag BAG (one of them)")
    if checkpoint_paths(out)[0].resolve() == checkpoint_paths(checkpoint)[0].resolve():
        raise typer.BadParameter(f"--out {out} is the checkpoint itself: give another path (nothing is overwritten)")
    run = Run.load(checkpoint)
    model = run.model
    check_calibratable(model)
    ds, source = load_bags(bag, run.meta.task, labeller) if bag else load_or_generate(data, None, 0, 0)
    if ds.state_size != model.config.input_size:
        raise typer.BadParameter(f"dataset states have size {ds.state_size}, the model takes {model.config.input_size}")
    labelled = np.flatnonzero(np.isfinite(ds.returns))
    if labels is not None:
        if labels > len(labelled):
            raise typer.BadParameter(f"--labels {labels}: the data has {len(labelled)} return-labelled episodes")
        labelled = np.sort(np.random.default_rng(seed).choice(labelled, labels, replace=False))
    ds = ds.subset(labelled)
    fit = fit_calibration(model, ds)
    calibrated = calibrate_model(model, fit)
    before, after = evaluate_model(model, ds), evaluate_model(calibrated, ds)
    m = int(model.serving_member)
    typer.echo(f"calibrated on {fit.labels} return labels ({source}): serving member's rewards were "
               f"{fit.gain[m]:.4g} r {fit.bias[m]:+.4g} per step; return MSE on them {before['return_mse']:.4f} -> "
               f"{after['return_mse']:.4f}")
    path = run.replace(model=calibrated, calibration={**fit.to_dict(), "from": str(checkpoint_paths(checkpoint)[0]),
                                                      "data": str(source)}).save(out)
    typer.echo(f"wrote {path}")


@app.command()
def explain(
    checkpoint: Path = typer.Option(..., help="checkpoint path (.pt or .json or the stem)"),
    out: Path = typer.Option(Path("runs/explain"), help="directory for the PNGs and index.html",
                             callback=writable_dir),
    bag: Path = typer.Option(None, help="a recording: embeddings of its episodes and per-episode views"),
    task: str = typer.Option(None, help="task (default: the checkpoint's)"),
    n: int = typer.Option(300, min=1, help="trajectories for the hidden-state embedding"),
    seed: int = typer.Option(1, min=0, help="data seed of the generated trajectories (without --bag)"),
    episodes: int = typer.Option(3, min=0, help="with --bag: how many per-episode views"),
) -> None:
    """Pictures of what a model learnt: hidden-state embeddings, reward maps, probe trajectories
    and (with --bag) recorded episodes, in OUT/index.html."""
    from ..interpret import explain as write_views

    figures = write_views(checkpoint, out, bag=bag, task=task, n=n, seed=seed, episodes=episodes)
    typer.echo(f"{len(figures)} figures: {out / 'index.html'}")


@app.command()
def check(
    checkpoint: Path = typer.Option(..., help="checkpoint path (.pt or .json or the stem)"),
    agent_episodes: int = typer.Option(150, min=1, help="episodes of the short agent run of the reward-hacking check"),
    eval_episodes: int = typer.Option(50, min=1, help="greedy and random episodes compared"),
    seed: int = typer.Option(0, min=0, help="agent seed (and of the check's episodes)"),
    memory_only: bool = typer.Option(False, help="skip the agent run (the memory check only)"),
    oracle: str = typer.Option("", help=ORACLE_HELP + "; the checks compare the model with it"),
) -> None:
    """Is this model fit to train an agent on? The memory check (does the served state separate
    what the oracle's hidden state separates) and the reward-hacking check (a short agent's
    learnt vs oracle return). Run it before training an agent; exit code 1 if a check fails."""
    from ..mil import load_checkpoint
    from ..rl.acceptance import hacking_check, memory_check, screened_episodes
    from ..tasks import check_task, has_environment

    model, meta = load_checkpoint(checkpoint)
    from ..oracles import make_oracle

    task = meta.task
    check_task(task)
    if not has_environment(task):
        raise ValueError(f"task {task!r} is a recorded dataset with no environment: nmrm check rolls out episodes "
                         f"and trains an agent in one (a model of a task spec with an environment can be checked)")
    make_oracle(task, oracle)
    typer.echo(f"checking {checkpoint} ({model.config.architecture} on {task})")
    screened = screened_episodes(task, seed=12345 + seed, oracle=oracle)  # both checks read them
    results = [memory_check(model, task, seed=12345 + seed, oracle=oracle, screened=screened)]
    typer.echo(results[-1].summary())
    if not memory_only:
        results.append(hacking_check(checkpoint, task, episodes=agent_episodes, eval_episodes=eval_episodes,
                                     seed=seed, oracle=oracle, screened=screened))
        typer.echo(results[-1].summary())
    if not all(r.passed for r in results):
        from ..rl.acceptance import next_step

        typer.echo(next_step(results, str(checkpoint), task, oracle))
        raise typer.Exit(1)


