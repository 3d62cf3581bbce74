"""Training runs end to end: `fit` splits a dataset, trains an ensemble of K models (K = 1: one
model), evaluates it on the test split(s) and returns a `Run` (saved if asked)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ..datasets.prefixes import cut_episodes
from ..datasets.trajectories import TrajectoryDataset
from ..tasks.gym_task import encoder_weights_changed
from .checkpoint import DataInfo, DataSource, EnsembleInfo
from .data import split_indices
from .ensemble import MILEnsemble, init_ensemble
from .evaluation import evaluate
from .fitted import fitted_members, label_variance, poorly_fitted
from .run import Run
from .training import TrainConfig, train_ensemble

SPLIT_MODES = ("shared", "per_member", "bootstrap")
#: draw d's members (cfg.redraws) are seeded as the first draw's plus d times this
REDRAW_SEED_STEP = 100_000


def member_splits(n: int, members: int, split_seed: int, mode: str,
                  offsets: list[int] | None = None) -> tuple[list, list]:
    """(K (train, val, test) index triples, the split seed of each member).

    shared: one 80/10/10 split (split_seed) for all; per_member: member m on split split_seed + m
    (the paper's repeats over splits); bootstrap: one split, each member's training set resampled
    with replacement from it (seed split_seed + m). `offsets` replaces m by offsets[m] (e.g. to
    rerun repeats 1, 3 and 8 of a 10-repeat table exactly)."""
    if mode not in SPLIT_MODES:
        raise ValueError(f"unknown split mode {mode!r}; use one of {', '.join(SPLIT_MODES)}")
    offsets = list(range(members)) if offsets is None else list(offsets)
    if len(offsets) != members:
        raise ValueError(f"{len(offsets)} member offsets for {members} members")
    if mode == "per_member":
        seeds = [split_seed + m for m in offsets]
        return [split_indices(n, s) for s in seeds], seeds
    train, val, test = split_indices(n, split_seed)
    if mode == "shared":
        return [(train, val, test)] * members, [split_seed] * members
    triples = [(np.sort(np.random.default_rng(split_seed + m).choice(train, len(train))), val, test)
               for m in offsets]
    return triples, [split_seed] * members


def in_step_units(ens: MILEnsemble, ds: TrajectoryDataset, feedback: str) -> tuple[MILEnsemble, dict]:
    """A model trained from comparisons alone, in units of its largest step on the episodes of
    `ds` (`calibration.step_units`: one gain for every member, so the served mean's order is
    unchanged), and the metrics entry that records it; any other model as it is, and {} (a model
    of comparisons whose architecture cannot be scaled: as it is, and the entry says why). Call it
    before the model is evaluated, so that its recorded metrics are of the model saved."""
    if feedback != "preferences":
        return ens, {}
    from .calibration import CalibrationError, calibrate, step_units

    try:
        units = step_units(ens, ds)
    except CalibrationError as exc:
        return ens, {"step_units": {"skipped": str(exc)}}
    return calibrate(ens, units), {"step_units": {"largest_step_reward": float(units.gain[0]),
                                                  "rewards": "r' / largest_step_reward"}}


class _Draw(NamedTuple):
    """One draw of K members (cfg.redraws): the trained ensemble, its seeds, its training result and
    each member's validation 1 - R^2 (None: nothing to judge by)."""
    ens: MILEnsemble
    seeds: list
    result: object  # training.EnsembleTrainResult
    unexplained: list | None
    cfg: TrainConfig  # what it trained with (`_patient`)


def _unexplained(result, cfg: TrainConfig) -> list | None:
    """Each member's best validation criterion over its validation labels' variance (1 - R^2;
    feedback returns), or None where there is nothing to judge by."""
    var = result.val_label_variance
    if cfg.feedback != "returns" or var is None or not all(v > 0 for v in var):
        return None
    return [float(v / w) for v, w in zip(result.best_val_loss, var)]


def _patient(cfg: TrainConfig, draw: int) -> TrainConfig:
    """The config of draw `draw` (0: cfg): patience and plateau_patience times
    cfg.redraw_patience ** draw."""
    if draw == 0 or cfg.redraw_patience == 1:
        return cfg
    factor = cfg.redraw_patience ** draw
    return replace(cfg, patience=max(1, round(cfg.patience * factor)),
                   plateau_patience=max(1, round(cfg.plateau_patience * factor)))


def _draws_record(draws: list, chosen: _Draw) -> dict:
    """metrics["draws"] when the run drew its members more than once (cfg.redraws): per draw its
    seeds, epochs, seconds and each member's validation 1 - R^2, and which draw was kept."""
    if len(draws) == 1:
        return {}
    return {"draws": [{"seeds": d.seeds, "epochs_run": d.result.epochs_run, "seconds": d.result.seconds,
                       "patience": [d.cfg.patience, d.cfg.plateau_patience], "unexplained": d.unexplained, "kept": d is chosen} for d in draws]}


def fit(ds: TrajectoryDataset, architecture: str, cfg: TrainConfig, members: int = 1, split_seed: int = 0,
        split_mode: str = "shared", out: str | Path | None = None, progress: bool = True,
        data_source: DataSource | None = None, on_epoch=None, offsets: list[int] | None = None) -> Run:
    """Train `members` models of `architecture` as one ensemble (1: a single model; member m:
    weights and shuffle seeded cfg.seed + m, split 80/10/10 per `split_mode`; offsets[m] instead
    of m if given), evaluate each member on its test split and the ensemble's mean on a shared
    one, pick the serving member (best validation criterion) and return the `Run` (saved to `out`
    if given; its metrics: test, val, member_test, member_val, best epochs...). data_source: where
    `ds` came from (recorded, so that `nmrm evaluate` can make it again). on_epoch: see `train_ensemble`. cfg.prefix_fraction > 0: the training and validation
    episodes are those of `cut_episodes(ds, cfg.prefix_fraction, seed=cfg.seed)` (some end early,
    labelled with the return earned by then); the test split is whole episodes. cfg.keep_members
    (K > 1): "all" serves every member; "best" keeps only the one best on validation (a 1-member
    ensemble); "fitted" (feedback returns) leaves out the members that did not fit
    (`fitted.fitted_members`). When members are left out the checkpoint records the candidates trained
    and which were kept. cfg.redraws = n > 0 (feedback returns): when no member of a draw explains
    more than 1 - `fitted.POORLY_FITTED` of its validation returns' variance and all of them
    stopped before the epoch limit (all stayed on a plateau), K new members are drawn (seeds +
    REDRAW_SEED_STEP) and trained, with cfg.redraw_patience times the patience (and plateau
    patience) of the draw before, up to n more times; the draw with the best member is kept
    (metrics["draws"] records them all); not with split_mode per_member, whose members are
    independent repeats, nor with cfg.label_swap > 0. ValueError (one line) for a dataset of a
    frozen encoder's features whose weights file now holds other weights
    (`gym_task.encoder_weights_changed`)."""
    changed = encoder_weights_changed(ds.task, ds.meta.get("encoder_sha256"))
    if changed:
        raise ValueError(f"the dataset's states are features of another encoder ({changed}): "
                         f"restore that file, or make the dataset again with the new encoder")
    trained_on = cut_episodes(ds, cfg.prefix_fraction, seed=cfg.seed) if cfg.prefix_fraction else ds
    splits, split_seeds = member_splits(len(ds), members, split_seed, split_mode, offsets)
    first_seeds = [cfg.seed + m for m in (range(members) if offsets is None else offsets)]
    config = cfg.model_config(architecture, ds.task, ds.state_size)
    fitted_only = cfg.keep_members == "fitted" and cfg.feedback == "returns" and members > 1
    draws: list[_Draw] = []
    # per_member splits are the paper's repeats: each is judged as it came, never drawn again; with
    # swapped labels (label_swap) the validation labels are noisy on purpose: 1 - R^2 cannot tell a plateau
    redraws = cfg.redraws if split_mode != "per_member" and cfg.label_swap == 0 else 0
    for draw in range(redraws + 1):
        seeds = [s + REDRAW_SEED_STEP * draw for s in first_seeds]
        ens, patient = init_ensemble(config, seeds), _patient(cfg, draw)
        result = train_ensemble(ens, trained_on, [(tr, va) for tr, va, _ in splits], patient,
                                seeds=seeds, progress=progress, on_epoch=on_epoch, leave_out_unfitted=fitted_only)
        draws.append(_Draw(ens, seeds, result, _unexplained(result, cfg), patient))
        u = draws[-1].unexplained
        if u is None or not poorly_fitted(min(u)) or any(result.still_improving):
            break  # a member fitted, nothing to judge by, or the epoch limit came first: no other draw
    chosen = min(draws, key=lambda d: min(d.result.best_val_loss))  # its best member is best on validation
    ens, seeds, result = chosen.ens, chosen.seeds, chosen.result
    serving = int(np.argmin(result.best_val_loss))  # the best on the validation criterion
    ens.serving_member.fill_(serving)
    kept, unexplained = list(range(members)), None
    if cfg.keep_members == "best":  # the others were candidates: one model is kept
        kept = [serving]
    elif fitted_only and chosen.unexplained is not None:
        # judged as training judged: its validation criterion over its validation labels' variance
        unexplained = chosen.unexplained
        kept = fitted_members(unexplained, serving)
    candidates = {}
    if len(kept) < members:  # the checkpoint records the candidates trained and those kept
        candidates = {"candidates": members, "candidate_seeds": seeds, "kept": kept,
                      "candidate_val_loss": [float(v) for v in result.best_val_loss],
                      **({"chosen": serving} if cfg.keep_members == "best" else {})}
        ens = MILEnsemble.from_members([ens.member(m) for m in kept])
        seeds, split_seeds, splits = [seeds[m] for m in kept], [split_seeds[m] for m in kept], [splits[m] for m in kept]
        members, serving = len(kept), kept.index(serving)
        ens.serving_member.fill_(serving)
    ens, units = in_step_units(ens, trained_on, cfg.feedback)  # before evaluating: the model saved
    member_test = [evaluate(ens.member(m), ds.subset(te)) for m, (_, _, te) in enumerate(splits)]
    member_val = [evaluate(ens.member(m), trained_on.subset(va)) for m, (_, va, _) in enumerate(splits)]
    test = val = None
    if members == 1:
        test, val = member_test[0], member_val[0]
    elif split_mode != "per_member":
        test, val = evaluate(ens, ds.subset(splits[0][2])), evaluate(ens, trained_on.subset(splits[0][1]))
    # what share of the validation returns' variance the served model leaves unexplained (1 - R^2)
    val_var = label_variance(trained_on.returns[splits[0][1]]) if val is not None and cfg.feedback == "returns" else 0.0
    served_unexplained = {"val_unexplained_variance": float(val["return_mse"] / val_var)} if val_var > 0 else {}
    run = Run.of(
        ens, ds.task, train=result, seed=cfg.seed, split_seed=split_seed, train_config=cfg.to_dict(),
        data=DataInfo(DataSource.parse(data_source) if isinstance(data_source, str) else data_source or DataSource(),
                      len(ds), ds.meta),
        ensemble=EnsembleInfo(members, serving, seeds, split_seeds, split_mode, **candidates),
        metrics={"test": test, "val": val, "member_test": member_test, "member_val": member_val,
                 "best_epochs": result.best_epochs, "still_improving": result.still_improving,
                 "epochs_run": result.epochs_run, "seconds": sum(d.result.seconds for d in draws),
                 # per epoch, each trained member's validation criterion: how it stopped
                 "val_loss_history": [[float(v) for v in h["val_loss"]] for h in result.history],
                 **({"candidate_unexplained_variance": unexplained} if unexplained is not None else {}),
                 **served_unexplained, **_draws_record(draws, chosen), **units})
    if out is not None:
        run.save(out)
    return run
