"""Mini-batch MIL training: Adam on the MSE of bag returns, early stopping on validation return
MSE, best weights kept; any number of models at once.

`train_ensemble` trains the K members of a `MILEnsemble` in one pass: every optimiser step takes
one mini-batch per member (from that member's own training split and its own shuffle), and the
loss is the sum of the members' losses, so with Adam (elementwise) each member follows its own
training exactly as if alone. Each member keeps its own best epoch and early-stopping clock; the
run ends when every member has run out of patience, or at `max_epochs`. `train_model` is the same
trainer for one model.

Unlike the paper (one bag per step), bags are trained in padded mini-batches; the loss is computed
on returns divided by `return_scale` (Lunar Lander: 100), as the paper scaled its targets.
Learning-rate schedule: linear warm-up over `warmup_epochs`, then
- constant, or a cosine decay to `lr * min_lr_ratio` at `max_epochs` (both global);
- plateau: stop on convergence, not at a cap. Each member keeps its own learning-rate factor
  (from 1): after `plateau_patience` epochs without a new best validation return MSE it is
  multiplied by `plateau_factor`, and the member is done once the factor is below
  `min_lr_ratio` (converged) or after `patience` epochs without a new best; the run ends when
  every member is done (`max_epochs` is only a safety limit). For `pipeline.fit` with keep_members
  fitted (K > 1, feedback returns) a member is also done once it is `plateau_patience` epochs past
  its last progress and has not fitted (`fitted.unfitted`): it would be left out of the served mean. A member's factor scales its Adam
  update (Adam's step is proportional to lr, weight decay included), so each member still trains
  exactly as it would alone; a done member is frozen. `grad_clip` > 0 clips each member's gradient norm.
Progress: the clocks (patience, and the plateau's cuts) restart only at an epoch whose validation
loss is below the last such epoch's by more than the fraction `min_improvement` (0: any new best);
the best weights are kept on any improvement. So creeping down by a fraction of a percent an epoch
does not hold a run open, and "still improving" at the cap means progress within the last `patience` epochs.
`label_swap` = p > 0 trains on noisy labels (paper Sec. 5.2): a fraction p of each member's
training labels, and of its validation labels, are swapped between trajectories
(`nmrm_ros.datasets.label_noise`; seeded by the member's seed); the test split stays clean.

`feedback` says what the labels are: `returns` (the paper: the MSE of bag returns), `preferences`
(pairwise comparisons, `TrajectoryDataset.preferences`: a Bradley–Terry cross-entropy on the two
trajectories' predicted returns, `preference_loss`; the CSC model's return is the sum of its
rewards, so the loss reaches every step) or `both` (the return MSE plus `preference_weight` times
the cross-entropy; trajectories without a return label, NaN, are left out of the MSE).
`prefix_fraction` = f > 0 (`pipeline.fit`): a seeded fraction f of the episodes
is cut at a random step and labelled with the return earned by then (`datasets.prefixes`; needs
the oracle's per-step rewards), for training and validation; the test split stays whole. Returns of
whole episodes cannot say *when* credit is earned; prefixes can.
Comparisons are split as the trajectories are: one with a trajectory of the test split is a test
comparison (never trained on); of the others, a seeded tenth (`comparison_split`) validates. The
validation criterion (early stopping, best weights, plateau cuts; `val_loss` in the history) is
the validation return MSE, the validation cross-entropy, or their sum as in the training loss.
Preferences fix the returns only up to an offset and a scale: a difference of `return_scale` in
predicted return means P(a better) = sigmoid(1) = 0.73 (a teacher of rationality β is matched when
return_scale = 1 / β); `both` with a few return labels calibrates both.

`reward_l1` = λ > 0 adds λ · mean over bags of Σ_t |r'_t| (in units of return_scale) to each
member's loss: a sparsity prior that chooses between decompositions the returns cannot tell
apart. When every bag has the same length, adding any zero-sum function of time f(t) to the
rewards (the LSTM can count steps) leaves every return unchanged, so the return loss alone does
not fix the per-step rewards; the L1 term's optimum along those directions is f(t) = the median
of -r_t, i.e. f = 0 wherever most bags get no reward at step t. Its pull on the returns is small:
at the optimum a bag's return is off by about λ / 2. It applies with feedback returns and both,
not with preferences alone: comparisons leave the rewards' scale free, so the prior only shrinks
it towards 0, where every comparison is a coin toss (Timer, 1000 perfect comparisons, seeds 0-2:
held-out preference accuracy 0.740 [worst 0.520] with λ 0.05, 0.913 [0.885] without;
bench/results/preferences/timer_no_l1/).
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
import yaml

from ..datasets.label_noise import swap_sources
from ..datasets.trajectories import TrajectoryDataset, concatenate
from .data import BagTensors, normalisation
from .. import feedback
from .fitted import label_variance, unfitted
from .ensemble import MILEnsemble, as_ensemble
from .models import OUTPUT_ACTIVATIONS, MILRewardModel, ModelConfig, model_config

CONFIG_FILE = Path(__file__).resolve().parents[2] / "config" / "mil_training.yaml"
SCHEDULES = ("constant", "cosine", "plateau")
KEEP_MEMBERS = ("fitted", "all", "best")  # which of the K members trained are served (pipeline.fit)
FEEDBACK = feedback.FEEDBACK  # the kinds of labels trained on (nmrm_ros/feedback.py)


@dataclass
class TrainConfig:
    """Hyperparameters of one training run (per task defaults in config/mil_training.yaml)."""

    lr: float = 5e-4
    weight_decay: float = 0.0
    dropout: float = 0.0
    patience: int = 50
    max_epochs: int = 250
    batch_size: int = 64
    return_scale: float = 1.0
    normalisation: str = "standard"
    seed: int = 0
    threads: int = 0  # torch threads while training; 0: torch's own setting (every core unless the process set fewer)
    schedule: str = "constant"  # constant | cosine | plateau
    warmup_epochs: int = 0
    min_lr_ratio: float = 0.0
    grad_clip: float = 0.0  # per-member gradient norm limit; 0 = off
    lstm_forget_bias: float = 0.0  # initial forget-gate bias (b_ih + b_hh) of every LSTM
    relu_bias: float = 0.0  # > 0: initial bias of every FC layer followed by a ReLU (0: torch's default init)
    hidden_size: int = 2  # LSTM state size of the model trained (paper: 2)
    output_activation: str = ""  # the head's output activation (models.OUTPUT_ACTIVATIONS; "": the task family's)
    fe_sizes: list | None = None  # feature-extractor layer widths, e.g. [64, 32, 32] (None: the task family's)
    head_sizes: list | None = None  # head hidden-layer widths, e.g. [32, 16]; [] for none (None: the family's)
    label_swap: float = 0.0  # fraction of training and validation labels swapped (label noise)
    reward_l1: float = 0.0  # weight of the mean per-bag sum of |r'_t| (label units / return_scale) in the loss
    members: int = 1  # models `nmrm train` trains as one ensemble (shared split) unless --ensemble is given
    served_state: str = "h_tanh_c"  # what the model serves by default (recorded in its checkpoint; mil.served_state)
    plateau_patience: int = 10  # schedule plateau: epochs without a new best before the lr is cut
    plateau_factor: float = 0.5  # schedule plateau: the cut
    min_improvement: float = 0.0  # progress: validation loss below the last progress epoch's by this fraction (resets the clocks)
    feedback: str = "returns"  # what the labels are: returns | preferences | both (see the module docstring)
    preference_weight: float = 1.0  # feedback both: weight of the preference cross-entropy beside the return MSE
    prefix_fraction: float = 0.0  # fraction of the training and validation episodes cut short (pipeline.fit)
    redraws: int = 0  # pipeline.fit: how many times K new members may be drawn when none fitted (mil.fitted.POORLY_FITTED)
    # pipeline.fit: draw d trains with patience and plateau_patience times redraw_patience ** d (a draw
    # that stayed on the plateau says the data needs more time than the defaults give). 2.0 is the
    # default here, not only in config/mil_training.yaml, so that models recorded before it existed
    # are not stale: it changes nothing in a run without a redraw (runs that redrew before 2026-12-07's
    # later commits used 1.0: bench/results/time_to_accuracy/redraw/ patrol s22)
    redraw_patience: float = 2.0
    keep_members: str = "all"  # all: the members' mean is served; best: only the best on validation; fitted (config/mil_training.yaml's default): all but those that did not fit (mil.fitted)

    def lr_at(self, epoch: float) -> float:
        """Learning rate at (fractional, 0-based) epoch."""
        if self.warmup_epochs > 0 and epoch < self.warmup_epochs:
            return self.lr * (epoch + 1e-3) / self.warmup_epochs
        if self.schedule == "cosine":
            span = max(self.max_epochs - self.warmup_epochs, 1)
            progress = min(max(epoch - self.warmup_epochs, 0.0) / span, 1.0)
            low = self.lr * self.min_lr_ratio
            return low + 0.5 * (self.lr - low) * (1.0 + math.cos(math.pi * progress))
        if self.schedule not in SCHEDULES:
            raise ValueError(f"unknown schedule {self.schedule!r}: use one of {', '.join(SCHEDULES)}")
        return self.lr  # constant; plateau: each member's factor is applied by the trainer

    def to_dict(self) -> dict:
        return asdict(self)

    def model_config(self, architecture: str, task: str, input_size: int) -> ModelConfig:
        """The model this config trains: the paper's `architecture` for `task`'s family with this
        config's dropout, LSTM size, output activation and (where set) layer widths."""
        return model_config(architecture, task, input_size, dropout=self.dropout,
                            hidden_size=self.hidden_size, output_activation=self.output_activation,
                            fe_sizes=self.fe_sizes, head_sizes=self.head_sizes)

    def check(self) -> "TrainConfig":
        """self, or a ValueError naming the first setting out of its range."""
        rules = [("lr", self.lr > 0, "> 0"), ("weight_decay", self.weight_decay >= 0, ">= 0"),
                 ("dropout", 0 <= self.dropout < 1, "in [0, 1)"), ("patience", self.patience >= 1, ">= 1"),
                 ("max_epochs", self.max_epochs >= 1, ">= 1"), ("batch_size", self.batch_size >= 1, ">= 1"),
                 ("return_scale", self.return_scale > 0, "> 0"),
                 ("normalisation", self.normalisation in ("standard", "minmax"), "standard or minmax"),
                 ("threads", self.threads >= 0, ">= 0 (0: torch's own setting)"),
                 ("schedule", self.schedule in SCHEDULES, " or ".join(SCHEDULES)),
                 ("warmup_epochs", self.warmup_epochs >= 0, ">= 0"),
                 ("min_lr_ratio", 0 <= self.min_lr_ratio <= 1, "in [0, 1]"),
                 ("grad_clip", self.grad_clip >= 0, ">= 0"), ("hidden_size", self.hidden_size >= 1, ">= 1"),
                 ("label_swap", 0 <= self.label_swap <= 1, "in [0, 1]"),
                 ("reward_l1", self.reward_l1 >= 0, ">= 0"), ("members", self.members >= 1, ">= 1"),
                 ("plateau_patience", self.plateau_patience >= 1, ">= 1"),
                 ("plateau_factor", 0 < self.plateau_factor < 1, "in (0, 1)"),
                 ("min_improvement", 0 <= self.min_improvement < 1, "in [0, 1)"),
                 ("served_state", self.served_state in ("h_tanh_c", "h_c", "h"), "h_tanh_c, h_c or h"),
                 ("feedback", self.feedback in FEEDBACK, " or ".join(FEEDBACK)),
                 ("preference_weight", self.preference_weight > 0, "> 0"),
                 ("keep_members", self.keep_members in KEEP_MEMBERS, " or ".join(KEEP_MEMBERS)),
                 ("redraws", self.redraws >= 0, ">= 0"),
                 ("redraw_patience", self.redraw_patience >= 1, ">= 1"),
                 ("prefix_fraction", 0 <= self.prefix_fraction <= 1
                  and (self.prefix_fraction == 0 or self.feedback == "returns"),
                  "in [0, 1], and 0 unless feedback is returns (it cuts return-labelled episodes)"),
                 ("output_activation", self.output_activation in ("",) + OUTPUT_ACTIVATIONS,
                  "empty (the task family's) or " + ", ".join(OUTPUT_ACTIVATIONS)),
                 ("fe_sizes", self.fe_sizes is None or (len(self.fe_sizes) >= 1 and _widths(self.fe_sizes)),
                  "one or more layer widths >= 1 (e.g. 64,32,32)"),
                 ("head_sizes", self.head_sizes is None or _widths(self.head_sizes),
                  "layer widths >= 1 (e.g. 32,16; empty for no hidden layer)")]
        for name, ok, allowed in rules:
            if not ok:
                raise ValueError(f"training setting {name} must be {allowed}, got {getattr(self, name)!r}")
        return self


@dataclass
class TrainResult:
    """One model's training. `still_improving`: it reached max_epochs with its best epoch within
    the last `patience` epochs, i.e. it stopped at the limit, not on a plateau. `best_val_loss`:
    the validation criterion at the best epoch (feedback returns: the return MSE)."""

    best_epoch: int
    best_val_loss: float
    epochs_run: int
    seconds: float
    still_improving: bool = False
    history: list = field(default_factory=list)  # per epoch: {"epoch", "train_loss" (None: a member done), "val_loss", "val_return_mse" and/or "val_preference_loss", "lr"}


@dataclass
class EnsembleTrainResult:
    """Per-member lists (length K) and the run's totals."""

    best_epochs: list
    best_val_loss: list
    still_improving: list
    epochs_run: int
    seconds: float
    history: list = field(default_factory=list)  # per epoch: lists of K train losses / val MSEs
    val_label_variance: list | None = None  # feedback returns: the variance of each member's validation labels

    def member(self, m: int) -> TrainResult:
        return TrainResult(self.best_epochs[m], self.best_val_loss[m], self.epochs_run,
                           self.seconds, self.still_improving[m],
                           [dict({k: h[k][m] for k in h if isinstance(h[k], list)},
                                 epoch=h["epoch"], lr=h["lr"]) for h in self.history])


#: settings that change how fast a model trains, not what it learns (the same weights either way: a
#: Key run on 1 and 2 threads gave the same held-out metrics to the last digit); benchmarks do not
#: count a run made with other values as stale
EXECUTION_SETTINGS = ("threads",)

OWN_TASK = "your_own_task"  # the config entry of a task spec (gym:<id>, module:attr) without one of its own


def load_train_config(task: str, path: str | Path | None = None, **overrides) -> TrainConfig:
    """The task's hyperparameters from the YAML config (its `defaults` merged with the task's
    entry; a task spec without an entry of its own takes `your_own_task`, a pixel task its state
    task's), then `overrides`
    (None values ignored). Feedback other than returns drops the task's prefix labels (prefix_fraction
    0) unless `overrides` set them."""
    with open(path or _config_path()) as f:
        table = yaml.safe_load(f)
    if ":" in task and task not in table and OWN_TASK in table:  # a task spec without an entry of its own
        task = OWN_TASK
    elif task not in table:  # a pixel task without an entry of its own: its state task's settings
        from ..tasks import TASKS, task_info

        task = task_info(task).pixels_of or task if task in TASKS else task
    if task not in table or task.startswith("_"):
        known = ", ".join(k for k in table if k != "defaults" and not k.startswith("_"))
        raise ValueError(f"no training config for {task!r} in {path or _config_path()}; known: {known}")
    values = dict(table.get("defaults", {}), **table[task])
    given = {k: v for k, v in overrides.items() if v is not None}
    if given.get("feedback", values.get("feedback", "returns")) != "returns" and "prefix_fraction" not in given:
        values["prefix_fraction"] = 0.0  # a task's prefix labels cut return-labelled episodes only
    values.update(given)
    unknown = set(values) - set(TrainConfig.__dataclass_fields__)
    if unknown:
        raise ValueError(f"unknown training settings {sorted(unknown)}")
    return TrainConfig(**{k: _coerce(k, v) for k, v in values.items()}).check()


def _widths(sizes) -> bool:
    return all(isinstance(w, int) and not isinstance(w, bool) and w >= 1 for w in sizes)


def _coerce(name: str, value):
    """A setting converted to its field's type ("1e-3" -> 0.001; 64.0 -> 64; "64,32" -> [64, 32]),
    or a clear error."""
    kind = TrainConfig.__dataclass_fields__[name].type
    if kind == "list | None":
        items = [v for v in value.replace(" ", "").split(",") if v] if isinstance(value, str) else value
        try:
            if any(isinstance(v, bool) or float(v) != int(float(v)) for v in items):
                raise ValueError
            return [int(float(v)) for v in items]
        except (TypeError, ValueError):
            raise ValueError(f"training setting {name} must be a list of layer widths (e.g. 64,32), "
                             f"got {value!r}") from None
    try:
        if kind == "float":
            return float(value)
        if kind == "int":
            if isinstance(value, bool) or float(value) != int(float(value)):
                raise ValueError
            return int(float(value))
    except (TypeError, ValueError):
        raise ValueError(f"training setting {name} must be a{'n' if kind == 'int' else ''} {kind}, "
                         f"got {value!r}") from None
    return value


def _config_path() -> Path:
    """config/mil_training.yaml of the source tree, else of the installed share directory."""
    if CONFIG_FILE.is_file():
        return CONFIG_FILE
    from ..ros.ament_paths import require_share_dir

    return require_share_dir("nmrm_ros") / "config" / "mil_training.yaml"


@torch.no_grad()
def return_mse(model: MILRewardModel | MILEnsemble, bags: BagTensors, batch_size: int = 512,
               scaled: bool = False, index: torch.Tensor | None = None,
               label_index: torch.Tensor | None = None) -> np.ndarray:
    """Mean squared error (K,) of each member's predicted returns (label units, or / return_scale)
    over the bags (or the bags at `index`: (n,), or (K, n) one row per member; against the labels
    of the bags at `label_index`, same shape, if given)."""
    model = as_ensemble(model).eval()
    if index is None:
        index = torch.arange(len(bags))
    if index.dim() == 1:
        index = index.unsqueeze(0).expand(model.members, -1)
    n = index.shape[-1]
    total = torch.zeros(model.members)
    batch_size = bags.eval_rows(batch_size, model.members)
    for start in range(0, n, batch_size):
        part = slice(start, start + batch_size)
        x, lengths, returns = bags.batch(index[..., part],
                                         None if label_index is None else label_index[..., part])
        err = model(x, lengths, patch_ordered=bags.patch_ordered).returns - returns
        if scaled:
            err = err / model.return_scale
        total += (err.double() ** 2).sum(-1)
    return total.numpy() / max(n, 1)


def train_model(model: MILRewardModel, train: TrajectoryDataset, val: TrajectoryDataset,
                cfg: TrainConfig, progress: bool = True) -> TrainResult:
    """Train one model in place (normalisation from `train`); on return it holds the best weights."""
    full = concatenate([train, val])
    n_train = len(train)
    splits = [(np.arange(n_train), np.arange(n_train, len(full)))]
    ens = MILEnsemble.from_members([model])
    result = train_ensemble(ens, full, splits, cfg, progress=progress)
    with torch.no_grad():
        trained = ens.member(0)
        model.load_state_dict(trained.state_dict())
    model.eval()
    return result.member(0)


def init_lstm_forget_bias(ens: MILEnsemble, value: float) -> None:
    """Set every member's forget-gate bias (b_ih + b_hh) to `value` (b_hh's part to 0)."""
    if not ens.uses_lstm:
        return
    k = ens.hidden_size
    with torch.no_grad():
        ens.params["lstm__bias_ih_l0"][:, k:2 * k] = value
        ens.params["lstm__bias_hh_l0"][:, k:2 * k] = 0.0


def init_relu_bias(ens: MILEnsemble, value: float) -> None:
    """Set the bias of every FC layer that a ReLU follows (the feature extractor's, the head's
    hidden ones) to `value` in every member, so that each unit starts active on most standardised
    inputs. With torch's default init a narrow layer (the toy models' 2 units) can start, or
    early in training end up, with a unit that is 0 on every instance: a dead ReLU gets no
    gradient and the model stays on the Markovian plateau (bench/results/toy/)."""
    with torch.no_grad():
        for layer in ens.relu_layers():
            ens.params[f"{layer}__bias"].fill_(value)


def initialise(ens: MILEnsemble, cfg: TrainConfig) -> None:
    """Apply the config's initialisation settings (`lstm_forget_bias`, `relu_bias`) to a freshly
    initialised ensemble."""
    if cfg.lstm_forget_bias:
        init_lstm_forget_bias(ens, cfg.lstm_forget_bias)
    if cfg.relu_bias:
        init_relu_bias(ens, cfg.relu_bias)


def clip_member_grad_norms(ens: MILEnsemble, max_norm: float) -> torch.Tensor:
    """Scale each member's gradient to norm <= max_norm; returns the norms before clipping (K,)."""
    grads = [p.grad for p in ens.parameters() if p.grad is not None]
    sq = sum((g.reshape(g.shape[0], -1) ** 2).sum(1) for g in grads)
    norms = sq.sqrt()
    factor = (max_norm / (norms + 1e-6)).clamp(max=1.0)
    for g in grads:
        g.mul_(factor.view(-1, *([1] * (g.dim() - 1))))
    return norms


def return_loss(out, returns: torch.Tensor, cfg: TrainConfig) -> torch.Tensor:
    """Each member's return loss (K,) on one mini-batch: the mean over bags of the squared return
    error / return_scale, plus `reward_l1` times the mean over bags of sum_t |r'_t| / return_scale.

    out: the ensemble's output (returns (K, B), rewards (K, B, T), zero beyond each length);
    returns: the labels (K, B)."""
    scale = float(cfg.return_scale)
    loss = torch.mean(((out.returns - returns) / scale) ** 2, dim=-1)
    return loss + _l1(out, cfg)


def _l1(out, cfg: TrainConfig) -> torch.Tensor:
    """reward_l1 times the mean over bags of sum_t |r'_t| / return_scale (K,), or 0."""
    if cfg.reward_l1 <= 0:  # sparsity prior on the per-step rewards (see the module docstring)
        return torch.zeros(())
    return cfg.reward_l1 * out.rewards.abs().sum(-1).mean(-1) / float(cfg.return_scale)


def preference_loss(returns_a: torch.Tensor, returns_b: torch.Tensor, p: torch.Tensor,
                    scale: float = 1.0) -> torch.Tensor:
    """The Bradley–Terry cross-entropy, mean over the last axis: P(a better) is modelled as
    sigmoid((R_a - R_b) / scale) and scored against the label p (1: a better, 0: b better,
    0.5: equal). returns_a, returns_b, p: (..., B) -> (...)."""
    logits = (returns_a - returns_b) / float(scale)
    return torch.nn.functional.binary_cross_entropy_with_logits(logits, p, reduction="none").mean(-1)


def comparison_split(preferences: np.ndarray | None, train: np.ndarray, val: np.ndarray,
                     seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(training rows, validation rows) of `preferences` (m, 3) for a member trained on the
    trajectories `train` and validated on `val`: comparisons of two trajectories of train ∪ val
    (one with a test trajectory is never used), a seeded ninth of them (a tenth of all when no
    trajectory is held out; at least one of two or more) validating, the rest training."""
    if preferences is None or len(preferences) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    known = np.zeros(int(max(preferences[:, :2].max() + 1, np.max(train, initial=0) + 1,
                             np.max(val, initial=0) + 1)), dtype=bool)
    known[np.asarray(train, dtype=np.int64)] = True
    known[np.asarray(val, dtype=np.int64)] = True
    a, b = preferences[:, 0].astype(np.int64), preferences[:, 1].astype(np.int64)
    usable = np.flatnonzero(known[a] & known[b])
    order = np.random.default_rng([int(seed), 0xC0]).permutation(usable)
    n_val = max(1, int(round(len(order) / 9))) if len(order) >= 2 else 0
    return np.sort(order[n_val:]), np.sort(order[:n_val])


def _tiled(rows: list, generators: list, length: int) -> torch.Tensor:
    """(K, length): member m's `rows` in a fresh random order (its generator), repeated as needed
    to reach `length` (members with fewer items see some twice in an epoch)."""
    out = []
    for m, r in enumerate(rows):
        r = torch.as_tensor(np.asarray(r), dtype=torch.int64)
        reps = -(-length // len(r))
        out.append(torch.cat([r[torch.randperm(len(r), generator=generators[m])] for _ in range(reps)])[:length])
    return torch.stack(out)


def _positions(step: int, batch: int, n: int, leading: bool) -> torch.Tensor:
    """Positions of mini-batch `step` in an epoch's order of n items: a slice when this stream
    sets the epoch (the last batch may be short), else full batches wrapping around."""
    if leading:
        return torch.arange(step * batch, min(n, (step + 1) * batch))
    return torch.arange(step * batch, (step + 1) * batch) % n


@torch.no_grad()
def _val_preference_loss(ens: MILEnsemble, bags: BagTensors, prefs: torch.Tensor, rows: list,
                         scale: float) -> np.ndarray:
    """Each member's mean Bradley–Terry cross-entropy on its validation comparisons (K,)."""
    ens.eval()
    out = np.zeros(len(rows))
    pairs = max(1, bags.eval_rows(512, ens.members) // 2)
    for m, r in enumerate(rows):
        r = torch.as_tensor(np.asarray(r), dtype=torch.int64)
        total = 0.0
        for start in range(0, len(r), pairs):
            pick = prefs[r[start:start + pairs]]
            ab = torch.cat([pick[:, 0], pick[:, 1]]).long()
            x, lengths, _ = bags.batch(ab)
            returns = ens(x, lengths, patch_ordered=bags.patch_ordered).returns[m]
            half = len(pick)
            total += float(preference_loss(returns[:half], returns[half:], pick[:, 2].float(), scale)) * half
        out[m] = total / max(len(r), 1)
    return out


def train_ensemble(ens: MILEnsemble, ds: TrajectoryDataset, splits: list, cfg: TrainConfig,
                   seeds: list | None = None, progress: bool = True,
                   on_epoch=None, label_swap: list | None = None,
                   fresh: bool = True, leave_out_unfitted: bool = False) -> EnsembleTrainResult:
    """Train every member of `ens` in place on `ds`.

    splits: K pairs (train indices, validation indices) into `ds`, one per member (equal train
    sizes); seeds: K seeds of the members' shuffles and dropout masks (default cfg.seed + m), so
    that member m trains exactly as it would alone with seeds[m]. Each member's normalisation is
    fitted on its own training split. on_epoch(entry) is called after each epoch with its history
    entry (plus "seconds": wall time since the start); returning True stops the run. On return each member
    holds its best-validation weights. label_swap: K fractions of swapped labels, one per member
    (default cfg.label_swap for all), e.g. to train a label-noise study as one ensemble.
    fresh: `ens` is newly initialised, so `initialise(ens, cfg)` is applied first; False for a
    warm start, whose trained weights are kept. cfg.feedback chooses the labels trained on (see
    the module docstring); ValueError if the dataset has none of that kind. leave_out_unfitted
    (feedback returns, K > 1, schedule plateau): a member on a plateau that did not fit
    (`fitted.unfitted`) is done at once, for a caller that leaves such members out (`pipeline.fit`
    with keep_members fitted); history then marks the epoch ("not_fitted": K bools).
    """
    K = ens.members
    if len(splits) != K:
        raise ValueError(f"{K} members need {K} splits, got {len(splits)}")
    sizes = {len(tr) for tr, _ in splits}
    if len(sizes) != 1:
        raise ValueError(f"members' training splits differ in size: {sorted(sizes)}")
    if len({len(va) for _, va in splits}) != 1:
        raise ValueError("members' validation splits differ in size")
    seeds = list(seeds) if seeds is not None else [cfg.seed + m for m in range(K)]
    use_returns, use_prefs = cfg.feedback in ("returns", "both"), cfg.feedback in ("preferences", "both")
    swaps = [cfg.label_swap] * K if label_swap is None else [float(p) for p in label_swap]
    if len(swaps) != K:
        raise ValueError(f"{K} members need {K} label swap fractions, got {len(swaps)}")
    if any(swaps) and cfg.feedback != "returns":
        raise ValueError("label_swap swaps return labels: it needs feedback returns")
    labelled = np.isfinite(ds.returns)
    if use_returns:
        missing = max(int((~labelled[np.asarray(tr)]).sum()) for tr, _ in splits)
        if cfg.feedback == "returns" and missing:
            raise ValueError(f"{missing} training trajectories have no return label (only comparisons): "
                             f"train with feedback preferences or both")
    if use_prefs:
        pair_rows = [comparison_split(ds.preferences, tr, va, s) for (tr, va), s in zip(splits, seeds)]
        if any(len(tr) == 0 for tr, _ in pair_rows):
            raise ValueError("no comparison of two training or validation trajectories to train on: "
                             f"feedback {cfg.feedback} needs preferences (the dataset has "
                             f"{0 if ds.preferences is None else len(ds.preferences)})")
        if any(len(va) == 0 for _, va in pair_rows):
            raise ValueError(f"too few comparisons to validate on ({min(len(tr) for tr, _ in pair_rows)} "
                             f"to train on, none left for validation): give at least 10")
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    torch.manual_seed(seeds[0])
    ens.seed_dropout(seeds)  # each member's masks from its own seed: a member is its own run
    for m, (tr, _) in enumerate(splits):
        shift, scale = normalisation(ds.subset(np.asarray(tr)), cfg.normalisation, ens.config.image_values)
        with torch.no_grad():
            ens.input_shift[m] = torch.as_tensor(shift, dtype=torch.float32)
            ens.input_scale[m] = torch.as_tensor(scale, dtype=torch.float32)
    ens.return_scale.fill_(float(cfg.return_scale))
    if fresh:
        initialise(ens, cfg)

    bags = BagTensors(ds, ens.patch_layout)  # pixels stored in the encoder's order, once
    bags.returns = torch.nan_to_num(bags.returns)  # unlabelled (NaN) bags never reach the MSE
    generators = [torch.Generator().manual_seed(int(s)) for s in seeds]
    if use_returns and cfg.feedback == "both" and not labelled.all():  # only the return-labelled ones
        labelled_splits = [(np.asarray(tr)[labelled[tr]], np.asarray(va)[labelled[va]]) for tr, va in splits]
        if any(len(tr) == 0 or len(va) == 0 for tr, va in labelled_splits):
            raise ValueError("feedback both needs return labels in the training and the validation split")
        width = [max(len(x[i]) for x in labelled_splits) for i in (0, 1)]
        train_idx = _tiled([tr for tr, _ in labelled_splits], generators, width[0])
        val_idx = _tiled([va for _, va in labelled_splits], generators, width[1])
    else:
        train_idx = torch.as_tensor(np.stack([np.asarray(tr) for tr, _ in splits]), dtype=torch.int64)
        val_idx = torch.as_tensor(np.stack([np.asarray(va) for _, va in splits]), dtype=torch.int64)
    n_train = train_idx.shape[1]
    # label noise: each member's training and validation labels swapped within its own split
    train_labels, val_labels = train_idx, val_idx
    if any(swaps):
        noise = [np.random.default_rng([int(s), 0x5A4B]) for s in seeds]
        train_labels = torch.stack([train_idx[m, swap_sources(n_train, swaps[m], noise[m])]
                                    for m in range(K)])
        val_labels = torch.stack([val_idx[m, swap_sources(val_idx.shape[1], swaps[m], noise[m])]
                                  for m in range(K)])
    prefs = torch.as_tensor(ds.preferences if use_prefs else np.zeros((0, 3)), dtype=torch.float64)
    n_pairs = max(len(tr) for tr, _ in pair_rows) if use_prefs else 0
    scale = float(cfg.return_scale)
    optimiser = torch.optim.Adam(ens.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    steps_returns = math.ceil(n_train / cfg.batch_size) if use_returns else 0
    steps_prefs = math.ceil(n_pairs / cfg.batch_size)
    steps_per_epoch = max(steps_returns, steps_prefs)
    best_mse = np.full(K, np.inf)
    best_epoch = np.zeros(K, dtype=int)
    progress_loss = np.full(K, np.inf)  # the loss at each member's last epoch of progress
    progress_epoch = np.zeros(K, dtype=int)
    best_state = [ens.member_state(m) for m in range(K)]
    # the variance of each member's validation labels (feedback returns): what fitted.unfitted judges by
    label_var = (np.array([label_variance(bags.returns[val_labels[m]].numpy()) for m in range(K)])
                 if cfg.feedback == "returns" else None)
    # (labels without variance: nobody is judged, as in fitted.unfitted)
    leave_out_unfitted = leave_out_unfitted and label_var is not None and K > 1 and bool((label_var > 0).all())
    history = []
    plateau = cfg.schedule == "plateau"
    factors = torch.ones(K, dtype=torch.float64)  # plateau: each member's lr factor (0: done)
    since_cut = np.zeros(K, dtype=int)  # plateau: epochs since the last new best or cut
    params = list(ens.parameters())
    start = time.perf_counter()
    bar = _progress(cfg.max_epochs, progress)
    epoch = 0
    for epoch in range(1, cfg.max_epochs + 1):
        ens.train()
        if use_returns:
            perms = torch.stack([torch.randperm(n_train, generator=generators[m]) for m in range(K)])
            order = train_idx.gather(1, perms)
            label_order = train_labels.gather(1, perms)
        if use_prefs:
            pair_order = _tiled([tr for tr, _ in pair_rows], generators, n_pairs)
        losses = torch.zeros(K)
        # the members still training (plateau: a member whose factor is 0 is done; its weights no
        # longer change, so its forward and backward are left out); None: all
        computed = None if not plateau or bool(factors.all()) else torch.nonzero(factors > 0).flatten()
        rows = slice(None) if computed is None else computed
        for step in range(steps_per_epoch):
            for group in optimiser.param_groups:
                group["lr"] = cfg.lr_at(epoch - 1 + step / steps_per_epoch)
            member_loss = torch.zeros(K)
            if use_returns:
                at = _positions(step, cfg.batch_size, n_train, steps_returns == steps_per_epoch)
                x, lengths, returns = bags.batch(order[rows][:, at], label_order[rows][:, at])
                member_loss = member_loss + _per_member(return_loss(ens(x, lengths, computed, bags.patch_ordered), returns, cfg),
                                                        computed, K)
            if use_prefs:
                pick = prefs[pair_order[rows][:, _positions(step, cfg.batch_size, n_pairs, steps_prefs == steps_per_epoch)]]
                half = pick.shape[1]
                x, lengths, _ = bags.batch(torch.cat([pick[..., 0], pick[..., 1]], dim=1).long())
                out = ens(x, lengths, computed, bags.patch_ordered)
                bt = preference_loss(out.returns[:, :half], out.returns[:, half:], pick[..., 2].float(), scale)
                member_loss = member_loss + _per_member(
                    cfg.preference_weight * bt + _l1(out, cfg) if use_returns else bt, computed, K)
            optimiser.zero_grad()
            member_loss.sum().backward()
            if cfg.grad_clip > 0:
                clip_member_grad_norms(ens, cfg.grad_clip)
            if plateau and bool((factors != 1).any()):
                scaled_step(optimiser, params, factors)
            else:
                optimiser.step()
            losses += member_loss.detach()
        train_loss = (losses / steps_per_epoch).tolist()
        if computed is not None:  # a member left out this epoch has no training loss
            kept = set(computed.tolist())
            train_loss = [v if m in kept else None for m, v in enumerate(train_loss)]
        entry = {"epoch": epoch, "train_loss": train_loss}
        val_loss = np.zeros(K)
        if use_returns:
            val_mse = return_mse(ens, bags, index=val_idx, label_index=val_labels)
            entry["val_return_mse"] = val_mse.tolist()
            val_loss = val_loss + (val_mse if cfg.feedback == "returns" else val_mse / scale ** 2)
        if use_prefs:
            val_bt = _val_preference_loss(ens, bags, prefs, [va for _, va in pair_rows], scale)
            entry["val_preference_loss"] = val_bt.tolist()
            val_loss = val_loss + (cfg.preference_weight if use_returns else 1.0) * val_bt
        entry["val_loss"] = val_loss.tolist()
        entry["lr"] = optimiser.param_groups[0]["lr"]
        history.append(entry)
        stop = on_epoch is not None and on_epoch(dict(history[-1], seconds=time.perf_counter() - start))
        for m in np.flatnonzero(val_loss < best_mse):  # the best weights: any improvement
            best_mse[m], best_epoch[m] = val_loss[m], epoch
            best_state[m] = ens.member_state(int(m))
        # progress (what resets the clocks): below the last progress by more than min_improvement
        improved = np.flatnonzero(val_loss < progress_loss * (1.0 - cfg.min_improvement))
        progress_loss[improved], progress_epoch[improved] = val_loss[improved], epoch
        if plateau:
            _plateau_update(factors, since_cut, improved, epoch - progress_epoch, cfg)
            if leave_out_unfitted:
                # on a plateau and unfitted (never the best on the criterion: it serves)
                stuck = ((factors.numpy() > 0) & (epoch - progress_epoch >= cfg.plateau_patience)
                         & unfitted(best_mse / label_var) & (np.arange(K) != int(np.argmin(best_mse))))
                factors[torch.as_tensor(stuck)] = 0.0
                if stuck.any():
                    history[-1]["not_fitted"] = stuck.tolist()  # done: on a plateau, did not fit
            history[-1]["lr_factor"] = factors.tolist()  # each member's, for the next epoch
        if bar is not None:
            bar.update(1)
            if K == 1:
                bar.set_postfix(val_loss=f"{val_loss[0]:.4f}", best=f"{best_mse[0]:.4f}@{best_epoch[0]}")
            else:
                bar.set_postfix(val_loss_median=f"{np.median(val_loss):.4f}",
                                worst_member_best=f"{best_mse.max():.4f}")
        if stop or np.all(epoch - progress_epoch >= cfg.patience) or (plateau and not bool(factors.any())):
            break
    if bar is not None:
        bar.close()
    for m in range(K):
        ens.load_member_state(m, best_state[m])
    ens.eval()
    # at the epoch limit with progress within the patience (plateau: not yet converged)
    still_improving = [bool(epoch - b < cfg.patience and (not plateau or factors[m] > 0))
                       for m, b in enumerate(progress_epoch)]
    return EnsembleTrainResult(best_epoch.tolist(), best_mse.tolist(), still_improving, epoch,
                               time.perf_counter() - start, history,
                               None if label_var is None else label_var.tolist())


def _per_member(loss: torch.Tensor, computed: torch.Tensor | None, K: int) -> torch.Tensor:
    """(K',) losses of the `computed` members -> (K,), 0 for the members left out."""
    return loss if computed is None else loss.new_zeros(K).index_add(0, computed, loss)


def scaled_step(optimiser: torch.optim.Optimizer, params: list, factors: torch.Tensor) -> None:
    """An optimiser step whose update of member m is scaled by factors[m] (K,) (0: unchanged).
    Exact for Adam: its update is proportional to the learning rate."""
    before = [p.detach().clone() for p in params]
    optimiser.step()
    with torch.no_grad():
        for p, old in zip(params, before):
            f = factors.to(p.dtype).view(-1, *([1] * (p.dim() - 1)))
            p.copy_(old + (p - old) * f)


def _plateau_update(factors: torch.Tensor, since_cut: np.ndarray, improved: np.ndarray,
                    since_best: np.ndarray, cfg: TrainConfig) -> None:
    """After an epoch: cut the factor of each member `plateau_patience` epochs past its last new
    best or cut; a member whose factor falls below `min_lr_ratio`, or that is `patience` epochs
    past its best, is done (factor 0)."""
    since_cut += 1
    since_cut[improved] = 0
    for m in np.flatnonzero((since_cut >= cfg.plateau_patience) & (factors.numpy() > 0)):
        factors[m] *= cfg.plateau_factor
        since_cut[m] = 0
    factors[torch.as_tensor(factors.numpy() < max(cfg.min_lr_ratio, 1e-12))] = 0.0
    factors[torch.as_tensor(since_best >= cfg.patience)] = 0.0


def _progress(total: int, enabled: bool):
    if not enabled:
        return None
    from tqdm import tqdm

    # disable=None: no bar when stderr is not a terminal (a log would get one \r-joined line)
    return tqdm(total=total, desc="epochs", unit="ep", leave=False, disable=None)


def parse_settings(pairs: list) -> dict:
    """["lr=1e-3", "schedule=cosine"] -> {"lr": 0.001, "schedule": "cosine"}: training settings given
    as name=value (YAML values; numbers as floats), for `load_train_config(task, **settings)`."""
    import yaml

    out = {}
    for pair in pairs or []:
        key, _, value = pair.partition("=")
        parsed = yaml.safe_load(value)
        if isinstance(parsed, str):  # YAML 1.1 reads "3e-3" (no dot) as a string
            try:
                parsed = float(parsed)
            except ValueError:
                pass
        out[key] = parsed
    return out
