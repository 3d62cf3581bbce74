"""Where Lunar Lander's CSC model pays its rewards, and what each fix does to it (issue 31).

    .venv/bin/python bench/lunar_lander_rewards.py --variants default reward_l1 mean_of_3 --seeds 0 1
    .venv/bin/python bench/lunar_lander_rewards.py --report
    .venv/bin/python bench/lunar_lander_rewards.py --returns     # what explains the returns (no training)

A model can fit the returns and still pay its rewards in the wrong places: every episode here has
500 steps, so a zero-sum function of time added to the rewards, or credit moved from one phase of
an episode to another, leaves every return unchanged (the deferred-credit analysis of Timer,
docs/results/findings.md). So besides the two MSEs, each run is scored by **where** it pays: on its
test split, the steps are grouped by the oracle's phase and component, and the model's mean reward
per step in each group is set beside the oracle's:

- pad: landing phase (fewer than 50 steps on the pad so far), both legs on the pad (oracle pays 1 + shaping);
- landing, off the pad: landing phase, elsewhere (shaping only);
- hover: after 50 steps on the pad, in the hover zone, no contact (1 + 1 + shaping);
- after, elsewhere: after 50 steps on the pad, outside the zone or touching the ground.

and the same groups along the "correct" probe (lands, stays 60 steps, hovers; `nmrm explain`).

Variants: changes to the recipe this study started from (BASE: the lunar_lander entry of
config/mil_training.yaml until 2026-12-04 — leaky ReLU output, cosine to 60 epochs, whole
episodes), so that a variant means the same whatever today's entry says (today's is
softplus_cut_converge):
default; reward_l1 (an L1 prior on per-step rewards, 0.05 as Timer's); mean_of_3 (members 3);
paper_lr (lr 1e-4 constant, 200 epochs, the paper's App. D.4 settings at our batch 32);
forget_bias_4 (the LSTM's initial forget-gate bias 4 instead of 1: a memory of ~50 steps at
initialisation instead of ~4; the return is explained by the steps airborne after 50 steps on the
pad (R^2 0.93 on data seed 0) and by no Markovian feature (R^2 < 0.01), so the model must count to
50 before its loss can improve); softplus (the head's output through softplus instead of the paper's
leaky ReLU of slope 1e-6: the default's stuck runs pay ~0 exactly where the oracle pays most, their
head's output there pushed to ~-500 before activation, where the leaky ReLU's gradient is 1e-6 —
the paper's App. F finds negative predictions in the runs stuck on its plateau); softplus_converge
(softplus, and the learning rate halved after 10 epochs without improvement instead of the cosine
to 60 epochs: the stop on convergence of Key and Charger, at most 300 epochs); softplus_cut
(softplus, and half the training and validation episodes cut at a random step, labelled with the
return earned by then: `prefix_fraction` 0.5, `nmrm_ros.datasets.prefixes`; the test split is
whole episodes), softplus_cut_all (every episode cut), softplus_cut_converge (softplus_cut with
softplus_converge's schedule).
Run (variant, seed s): weights s + 1000 j, split s, of the screened dataset of data seed 0 (5000
episodes; column "data": the scripted plans that made it, `nmrm_ros.tasks.lunar_lander.SCRIPTED_PLANS`
— every run in the table before 2026-12-04 is on plans 1, a run made today on today's plans). Resumes: each run's result is bench/results/lunar_lander/rewards/<variant>_s<s>.json; its
checkpoint runs/lunar_lander_rewards/<variant>_s<s>.pt (`nmrm explain --checkpoint` draws its
reward maps and probes).
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
import json
import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results" / "lunar_lander" / "rewards"
MODELS = ROOT / "runs" / "lunar_lander_rewards"  # each run's checkpoint, for `nmrm explain` (not in git)
BASE = {"output_activation": "leaky_relu", "schedule": "cosine", "max_epochs": 60, "prefix_fraction": 0.0,
        "members": 1}
VARIANTS = {
    "default": {},
    "reward_l1": {"reward_l1": 0.05},
    "mean_of_3": {"members": 3},
    "paper_lr": {"lr": 1e-4, "max_epochs": 200, "schedule": "constant", "warmup_epochs": 0},
    "forget_bias_4": {"lstm_forget_bias": 4.0},
    "softplus": {"output_activation": "softplus"},
    "softplus_converge": {"output_activation": "softplus", "schedule": "plateau", "plateau_patience": 10,
                          "plateau_factor": 0.5, "max_epochs": 300},
    "softplus_cut": {"output_activation": "softplus", "prefix_fraction": 0.5},
    "softplus_cut_all": {"output_activation": "softplus", "prefix_fraction": 1.0},
    "softplus_cut_converge": {"output_activation": "softplus", "prefix_fraction": 0.5, "schedule": "plateau",
                              "plateau_patience": 10, "plateau_factor": 0.5, "max_epochs": 300},
}
GROUPS = ("pad", "landing, off the pad", "hover", "after, elsewhere")


def phase_groups(states: np.ndarray, lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(group index (n, L) int, -1 beyond a length; oracle rewards (n, L)) of trajectories."""
    from nmrm_ros.oracles import make_oracle
    from nmrm_ros.oracles.lunar_lander import PAD_TARGET

    oracle = make_oracle("lunar_lander")
    labels = oracle.label(states, lengths=lengths)
    parts = oracle.label_components(states, lengths)
    landing = labels.hidden[..., 0] < PAD_TARGET
    group = np.where(landing, np.where(parts["pad"] > 0, 0, 1), np.where(parts["hover"] > 0, 2, 3))
    live = np.arange(states.shape[1])[None, :] < lengths[:, None]
    return np.where(live, group, -1), labels.rewards


def learnt_rewards(model, states: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """The model's per-step rewards (n, L) (the members' mean), stepped online as served."""
    from nmrm_ros.mil import OnlineRewardModel

    online = OnlineRewardModel(model)
    out = np.zeros(states.shape[:2])
    for i, (episode, n) in enumerate(zip(states, lengths)):
        out[i, :n] = online.episode_rewards(episode[:n])
    return out


def placement(group: np.ndarray, learnt: np.ndarray, oracle: np.ndarray) -> dict:
    """group name -> {steps, learnt, oracle}: mean reward per step of each."""
    return {name: {"steps": int((group == g).sum()),
                   "learnt": float(learnt[group == g].mean()) if (group == g).any() else float("nan"),
                   "oracle": float(oracle[group == g].mean()) if (group == g).any() else float("nan")}
            for g, name in enumerate(GROUPS)}


def run(job: tuple) -> dict:
    variant, seed = job
    done = RESULTS / f"{variant}_s{seed}.json"
    if done.is_file():
        return json.loads(done.read_text())
    import torch

    torch.set_num_threads(1)
    from nmrm_ros.datasets.cache import cached_dataset
    from nmrm_ros.interpret.lander_probes import rollout_probe, LANDER_PROBES
    from nmrm_ros.mil import load_train_config
    from nmrm_ros.mil.data import split_indices
    from nmrm_ros.mil.pipeline import fit

    ds = cached_dataset("lunar_lander", 5000, 0)
    overrides = BASE | VARIANTS[variant]
    cfg = load_train_config("lunar_lander", seed=seed, **overrides)
    t0 = time.perf_counter()
    result = fit(ds, "csc_lstm", cfg, cfg.members, split_seed=seed, progress=False,
                                offsets=[1000 * j for j in range(cfg.members)],
                                out=MODELS / f"{variant}_s{seed}")
    seconds = time.perf_counter() - t0
    _, _, test = split_indices(len(ds), seed)
    sub = ds.subset(test)
    group, oracle = phase_groups(sub.states, sub.lengths)
    learnt = learnt_rewards(result.model, sub.states, sub.lengths)
    probe = next(p for p in LANDER_PROBES if p.name == "correct")
    p_states = rollout_probe(probe)[None]
    p_len = np.array([p_states.shape[1]])
    p_group, p_oracle = phase_groups(p_states, p_len)
    p_learnt = learnt_rewards(result.model, p_states, p_len)
    res = {"variant": variant, "seed": seed, "plans": ds.meta.get("plans", 1), "overrides": overrides, "members": cfg.members,
           "test": result.test_metrics, "epochs": result.train.epochs_run,
           "best_epochs": result.train.best_epochs, "still_improving": result.train.still_improving,
           "seconds": seconds, "test_placement": placement(group, learnt, oracle),
           "probe_correct": placement(p_group, p_learnt, p_oracle),
           "probe_returns": {"learnt": float(p_learnt.sum()), "oracle": float(p_oracle.sum())}}
    RESULTS.mkdir(parents=True, exist_ok=True)
    done.write_text(json.dumps(res, indent=1, default=float))
    return res


def report() -> str:
    runs = sorted((json.loads(p.read_text()) for p in RESULTS.glob("*.json")), key=lambda r: (r["variant"], r["seed"]))
    lines = ["# bench/lunar_lander_rewards.py: CSC on Lunar Lander (data seed 0, split = weight seed s); mean reward per "
             "step, learnt / oracle, by the oracle's phase (test split, and the 'correct' probe)",
             f"{'variant':10s} {'s':>2s} {'data':>4s} {'ret MSE':>8s} {'rew MSE':>9s} "
             + " ".join(f"{g:>22s}" for g in GROUPS) + f" {'probe: ' + ' / '.join(GROUPS):>60s}  epochs"]
    for r in runs:
        t = r["test_placement"]
        p = r["probe_correct"]
        cells = " ".join(f"{t[g]['learnt']:9.3f} / {t[g]['oracle']:9.3f}" for g in GROUPS)
        probe = " ".join(f"{p[g]['learnt']:6.2f}/{p[g]['oracle']:5.2f}" for g in GROUPS)
        lines.append(f"{r['variant']:10s} {r['seed']:2d} {'p' + str(r.get('plans', 1)):>4s} "
                     f"{r['test']['return_mse']:8.3f} {r['test']['reward_mse']:9.5f} "
                     f"{cells} {probe:>60s}  {r['epochs']}")
    text = "\n".join(lines)
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "table.txt").write_text(text + "\n")
    return text


def return_analysis(n: int = 5000, seed: int = 0) -> str:
    """What explains Lunar Lander's returns (data seed `seed`, n episodes): R^2 of a linear fit of
    the return on one per-episode count at a time (Markovian counts, and the steps airborne once k
    steps on the pad have been counted, for several k), and each oracle component's share."""
    from nmrm_ros.datasets.cache import cached_dataset
    from nmrm_ros.oracles import make_oracle

    ds = cached_dataset("lunar_lander", n, seed)
    s, returns = ds.states, ds.returns
    live = np.arange(s.shape[1])[None, :] < ds.lengths[:, None]
    contact = ((s[..., 6] == 1) | (s[..., 7] == 1)) & live
    airborne = ~contact & live
    on_pad = (s[..., 6] == 1) & (s[..., 7] == 1) & (np.abs(s[..., 0]) <= 0.2) & live
    in_zone = (np.abs(s[..., 0]) <= 0.5) & (s[..., 1] >= 0.75) & (s[..., 1] <= 1.25) & live
    counted = np.cumsum(on_pad, 1)

    def r2(feature: np.ndarray) -> float:
        x = np.stack([feature, np.ones_like(feature)], 1).astype(np.float64)
        fit = x @ np.linalg.lstsq(x, returns, rcond=None)[0]
        return 1.0 - float(((returns - fit) ** 2).mean() / returns.var())

    lines = [f"# bench/lunar_lander_rewards.py --returns: what explains the returns of {n} screened episodes "
             f"(data seed {seed}; return mean {returns.mean():.1f}, std {returns.std():.1f})",
             "# R^2 of a linear fit of the return on one count per episode:"]
    for name, f in (("steps airborne", airborne), ("steps on the pad (both legs)", on_pad),
                    ("steps in the hover zone", in_zone)):
        lines.append(f"{name:45s} {r2(f.sum(1)):6.3f}")
    for k in (1, 10, 20, 30, 40, 50, 60):
        lines.append(f"{'steps airborne after ' + str(k) + ' on the pad':45s} {r2((airborne & (counted >= k)).sum(1)):6.3f}")
    parts = make_oracle("lunar_lander").label_components(s, ds.lengths)
    lines.append("# oracle components: mean, std of the per-episode sum, correlation with the return")
    for name, part in parts.items():
        total = part.sum(1)
        lines.append(f"{name:45s} {total.mean():7.1f} {total.std():7.1f} {np.corrcoef(total, returns)[0, 1]:6.2f}")
    text = "\n".join(lines)
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "returns.txt").write_text(text + "\n")
    return text


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--variants", nargs="*", default=list(VARIANTS), choices=list(VARIANTS))
    parser.add_argument("--seeds", nargs="*", type=int, default=[0, 1])
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--report", action="store_true", help="train nothing: the table of what is there")
    parser.add_argument("--returns", action="store_true",
                        help="train nothing: what explains the returns (bench/results/lunar_lander/rewards/returns.txt)")
    args = parser.parse_args()
    if args.returns:
        print(return_analysis())
        return
    if not args.report:
        jobs = [(v, s) for s in args.seeds for v in args.variants if not (RESULTS / f"{v}_s{s}.json").is_file()]
        print(f"# {len(jobs)} runs (finished ones skipped), {args.jobs} workers", flush=True)
        with ProcessPoolExecutor(args.jobs) as pool:
            for (v, s), r in zip(jobs, pool.map(run, jobs)):
                print(f"  {v} seed {s}: return MSE {r['test']['return_mse']:.3f}, reward MSE "
                      f"{r['test']['reward_mse']:.5f} ({r['seconds']:.0f} s)", flush=True)
    print(report())


if __name__ == "__main__":
    main()
