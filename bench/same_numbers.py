"""Same numbers before and after a refactor: fixed-seed runs of every architecture, saved and compared.

    .venv/bin/python bench/same_numbers.py --save runs/same_numbers/before.npz     # on the old commit
    .venv/bin/python bench/same_numbers.py --compare runs/same_numbers/before.npz  # on the new one

For each architecture and K = 1 and 3 members: 3 epochs of training (config key, dropout on) on 400
screened Key episodes of data seed 999 (per-member splits, weight seeds 0..K-1), then the best
validation losses, the batched forward (returns, rewards, hidden states) of 8 episodes, each served
state kind of them (`served_states`), the online stepper's rewards and served states along one
episode, and member 0's own forward. --compare prints the largest difference of each quantity and
exits 1 if a training or forward result differs at all (served states may differ by float32
rounding: they are computed by the ensemble's forward since 3c35690).
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
import sys
from pathlib import Path

import numpy as np
import torch

from nmrm_ros.datasets import generate_screened
from nmrm_ros.mil import ARCHITECTURES, OnlineRewardModel, load_train_config
from nmrm_ros.mil.ensemble import init_ensemble
from nmrm_ros.mil.pipeline import member_splits
from nmrm_ros.mil.served_state import served_states
from nmrm_ros.mil.training import train_ensemble



def _rounding_allowed(key: str) -> bool:
    """The batched served states may differ by float32 rounding; nothing else may differ."""
    return "_served_" in key and "_online_" not in key


def run() -> dict:
    ds = generate_screened("key", 400, seed=999)
    out = {}
    for arch in ARCHITECTURES:
        for K in (1, 3):
            cfg = load_train_config("key", max_epochs=3, patience=10, members=K)
            splits, _ = member_splits(len(ds), K, 0, "per_member")
            ens = init_ensemble(cfg.model_config(arch, "key", ds.state_size), range(K))
            res = train_ensemble(ens, ds, [(tr, va) for tr, va, _ in splits], cfg, progress=False)
            key = f"{arch}{K}"
            out[f"{key}_val"] = np.array(res.best_val_loss)
            x, lengths = torch.as_tensor(ds.states[:8], dtype=torch.float32), torch.as_tensor(ds.lengths[:8])
            with torch.no_grad():
                o = ens(x, lengths)
                out[f"{key}_member_ret"] = ens.member(0)(x, lengths).returns.numpy()
            out[f"{key}_ret"], out[f"{key}_rew"], out[f"{key}_hid"] = o.returns.numpy(), o.rewards.numpy(), o.hidden.numpy()
            for kind in ("h_tanh_c", "h"):
                out[f"{key}_served_{kind}"] = served_states(ens, ds.states[:8], ds.lengths[:8], kind=kind)
                online = OnlineRewardModel(ens, served=kind)
                steps = [online.step(s) for s in ds.states[0][:ds.lengths[0]]]
                out[f"{key}_online_{kind}"] = np.array([r for r, _ in steps])
                out[f"{key}_online_served_{kind}"] = np.array([h for _, h in steps])
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    what = parser.add_mutually_exclusive_group(required=True)
    what.add_argument("--save", type=Path, help="write this commit's numbers to this .npz")
    what.add_argument("--compare", type=Path, help="compare this commit's numbers with an .npz written by --save")
    a = parser.parse_args()
    if a.compare is not None:
        if not a.compare.is_file():
            sys.exit(f"same_numbers: no such file {a.compare} (write it with --save on the old commit)")
        try:
            before = np.load(a.compare)
            before.files
        except (OSError, ValueError, AttributeError) as exc:
            sys.exit(f"same_numbers: {a.compare} is not an .npz written by --save ({type(exc).__name__})")
    else:
        try:  # before a minute of work: a path that cannot be written is said now
            a.save.parent.mkdir(parents=True, exist_ok=True)
            (a.save if a.save.suffix == ".npz" else Path(f"{a.save}.npz")).touch()  # where np.savez writes
        except OSError as exc:
            sys.exit(f"same_numbers: cannot write {a.save}: {exc.strerror or exc}")
    out = run()
    if a.save is not None:
        np.savez(a.save, **out)
        print(f"wrote {len(out)} arrays to {a.save}")
        return
    if set(before.files) != set(out):
        sys.exit(f"same_numbers: the runs hold different quantities: only before {sorted(set(before.files) - set(out))}, "
                 f"only now {sorted(set(out) - set(before.files))}")
    changed = 0
    for k in before.files:
        old, new = before[k], out[k]
        if old.shape != new.shape or not np.array_equal(old, new, equal_nan=True):
            diff = float(np.nanmax(np.abs(old - new))) if old.shape == new.shape and old.size else float("nan")
            print(f"{k}: " + (f"largest difference {diff:.3g}" if old.shape == new.shape
                              else f"shape {old.shape} before, {new.shape} now")
                  + (", NaN where the other has a number" if old.shape == new.shape and
                     (np.isnan(old) != np.isnan(new)).any() else ""))
            exact_ok = old.shape == new.shape and not (np.isnan(old) != np.isnan(new)).any()
            changed += not (exact_ok and _rounding_allowed(k))
    print(f"{len(before.files)} arrays compared; {changed} training/forward/online results differ")
    sys.exit(1 if changed else 0)


if __name__ == "__main__":
    main()
