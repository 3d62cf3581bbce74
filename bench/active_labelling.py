"""How many labels the active ordering needs, versus oldest first: Key, the oracle playing the person.

The real nodes: `replay` plays a pool of screened Key episodes (a bag, in a random order seeded
by the repeat's seed) to `labeller_web` and
`trainer`; a simulated person answers the page's HTTP API: it takes the first episode of the
queue and posts the oracle's return, `--batch` labels at a time, then waits for the trainer's
next version (and, in the active arm, for the page to reorder by it) before going on, as a person
would label while the model retrains. Arms: `active` (the trainer sets labeller_web's checkpoint:
largest ensemble disagreement first) and `oldest` (the trainer does not: oldest first). Both start
with the same oldest-first batch (there is no model yet). Each version is scored afterwards on a
held-out screened test set (another data seed) with oracle rewards: return and reward MSE of the
ensemble mean.

    .venv/bin/python bench/active_labelling.py --seeds 0 1 2 --labels 300 --batch 20 --pool 600
    .venv/bin/python bench/active_labelling.py ... --screener-order --out bench/results/active_labelling_screener_order
    .venv/bin/python bench/active_labelling.py --feedback preferences --labels 300 --batch 20 --pool 600
Writes bench/results/active_labelling.{json,txt,png} (--feedback preferences: active_preferences.*).
Resumes: the JSON is rewritten after every (arm, seed); a run with the same settings skips the
(arm, seed) pairs it already holds (other seeds may be added later).

With `--feedback preferences` the person compares instead: it takes the first pair the page
offers (`/api/pairs`; active arm: the pairs whose P(left better) the members disagree on most,
among the `--pair-window` oldest episodes needing comparisons; oldest arm: the oldest pairs) and
posts the oracle's answer (a perfect teacher); the trainer learns from the comparisons. Versions
are scored by held-out preference accuracy and reward correlation (scale-free).
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

import numpy as np
from nmrm_ros.ros.ament_paths import node_command

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "bench" / "results"
#: the two test metrics reported per feedback
KEYS = {"returns": ("return_mse", "reward_mse"), "preferences": ("preference_accuracy", "reward_correlation")}


class Proc:
    """A node process whose output lines are collected by a thread."""

    def __init__(self, name: str, **params) -> None:
        self.proc = subprocess.Popen(node_command(name, **params), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                     env=os.environ.copy())
        self.lines: list = []
        self.thread = threading.Thread(target=lambda: self.lines.extend(self.proc.stdout), daemon=True)
        self.thread.start()

    def wait_for(self, pattern: str, count: int = 1, timeout: float = 600.0) -> str:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            found = [line for line in list(self.lines) if re.search(pattern, line)]
            if len(found) >= count:
                return found[count - 1]
            if self.proc.poll() is not None:
                break
            time.sleep(0.1)
        raise RuntimeError(f"no {count}x {pattern!r} in:\n{''.join(self.lines[-30:])}")

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
        self.proc.wait(30)


def api(base: str, path: str, body=None):
    """The page's answer to GET `path` (or POST `body`); `base` is the page's URL, token included."""
    from nmrm_ros.labelling.client import PageClient

    client = PageClient(base, timeout=30)
    return client.get(path) if body is None else client.post(path, body)


def run_arm(arm: str, seed: int, pool_bag: Path, returns: dict, work: Path, args) -> list:
    """Label args.labels episodes through the page; returns [(labels, checkpoint path, seconds)]."""
    os.environ["ROS_DOMAIN_ID"] = str(100 + seed * 2 + (arm == "active"))
    out = work / f"{arm}_{seed}"
    web = Proc("labeller_web", task="key", port=0, person="sim", labels_dir=out / "labels",
               max_episodes=len(returns), feedback=args.feedback, pair_window=args.pair_window)
    trainer = Proc("trainer", task="key", retrain_every=args.batch, members=args.members,
                   max_epochs=args.max_epochs, seed=seed, out_dir=out / "checkpoints",
                   reward_model="''", labeller_web="labeller_web" if arm == "active" else "''",
                   feedback=args.feedback)
    base = web.wait_for("labelling page: ", timeout=60).split("labelling page: ")[1].split()[0]
    replay = Proc("replay", bag=pool_bag, topics="[/nmrm/observation]", wait_for_subscribers=2,
                  wait_for_nodes="[labeller_web, trainer]", start_delay=1.0)
    versions = []
    t0 = time.monotonic()
    try:
        replay.wait_for(r"done|finished|replayed", timeout=300)
        deadline = time.monotonic() + 120
        while len(api(base, "/api/queue")["episodes"]) < len(returns):
            if time.monotonic() > deadline:
                raise RuntimeError(f"the page has {len(api(base, '/api/queue')['episodes'])} of "
                                   f"{len(returns)} episodes")
            time.sleep(0.5)
        for version in range(1, args.labels // args.batch + 1):
            for _ in range(args.batch):
                if args.feedback == "preferences":
                    pair = api(base, "/api/pairs")["pairs"][0]
                    ra, rb = returns[pair["a"]], returns[pair["b"]]
                    answer = "a" if ra > rb else "b" if rb > ra else "equal"
                    api(base, "/api/compare", {"a": pair["a"], "b": pair["b"], "preference": answer})
                    continue
                first = api(base, "/api/queue")["episodes"][0]
                api(base, "/api/label", {"episode": first["episode"], "return": returns[first["episode"]]})
            name = f"key_v{version:03d}"
            trainer.wait_for(rf"{name}: \d+ labels")
            if arm == "active":
                trainer.wait_for("labeller_web loads", count=version)
            versions.append((version * args.batch, str(out / "checkpoints" / name), time.monotonic() - t0))
            print(f"  [{arm} seed {seed}] {name}: {version * args.batch} labels, {time.monotonic() - t0:.0f} s",
                  flush=True)
    finally:
        for p in (replay, trainer, web):
            p.stop()
    return versions


#: the settings two sittings must share to be one result (the seeds may differ)
SETTINGS = ("labels", "batch", "pool", "test", "members", "max_epochs", "screener_order", "feedback", "pair_window")


def resumed_rows(args) -> tuple[list, dict]:
    """The rows and per-(arm, seed) seconds already in args.out's JSON, if its settings are args'.

    An (arm, seed) counts only when all its versions are there. A JSON of other settings is an
    error (one line), not overwritten: pass another --out.
    """
    path = args.out.with_suffix(".json")
    if not path.exists():
        return [], {}
    saved = json.loads(path.read_text())
    differ = [k for k in SETTINGS if saved["args"].get(k) != str(getattr(args, k))]
    if differ:
        sys.exit(f"error: {path} holds a run with other settings ({', '.join(differ)}); pass another --out")
    rows = saved["rows"]
    arm_seconds = saved.get("arm_seconds")
    if arm_seconds is None:  # a file of one sitting, before resuming existed: its wall time spread evenly
        pairs = sorted({f"{r['arm']}_{r['seed']}" for r in rows})
        arm_seconds = {k: saved["wall_seconds"] / len(pairs) for k in pairs}
    versions = args.labels // args.batch
    done = {k for k in arm_seconds
            if sum(1 for r in rows if f"{r['arm']}_{r['seed']}" == k) == versions}
    print(f"# resuming {path}: {sorted(done)} done", flush=True)
    return [r for r in rows if f"{r['arm']}_{r['seed']}" in done], {k: arm_seconds[k] for k in done}


def write_json(args, rows: list, arm_seconds: dict) -> None:
    """args.out's JSON: settings, rows and per-(arm, seed) seconds (written after every arm)."""
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps(
        {"args": {k: str(v) for k, v in vars(args).items()}, "rows": rows, "arm_seconds": arm_seconds,
         "wall_seconds": sum(arm_seconds.values())}, indent=1))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--labels", type=int, default=200)
    parser.add_argument("--batch", type=int, default=20)
    parser.add_argument("--pool", type=int, default=500, help="screened Key episodes offered (data seed 1)")
    parser.add_argument("--test", type=int, default=500, help="screened Key test episodes (data seed 2)")
    parser.add_argument("--members", type=int, default=5)
    parser.add_argument("--max-epochs", type=int, default=40)
    parser.add_argument("--screener-order", action="store_true",
                        help="play the pool in the screener's order (key-then-treasure episodes last)")
    parser.add_argument("--feedback", default="returns", choices=["returns", "preferences"])
    parser.add_argument("--pair-window", type=int, default=30, help="--feedback preferences: labeller_web's pair_window")
    parser.add_argument("--out", type=Path, default=None, help="default bench/results/active_labelling "
                                                              "(--feedback preferences: active_preferences)")
    args = parser.parse_args()
    if args.out is None:
        args.out = RESULTS / ("active_preferences" if args.feedback == "preferences" else "active_labelling")

    from nmrm_ros.bags import write_dataset_bag
    from nmrm_ros.datasets import generate_screened
    from nmrm_ros.mil import evaluate, load_checkpoint

    rows, arm_seconds = resumed_rows(args)
    start = time.monotonic()
    pool = generate_screened("key", args.pool, seed=1)
    test = generate_screened("key", args.test, seed=2)
    work = Path(tempfile.mkdtemp(prefix="active_labelling_"))
    for seed in args.seeds:
        todo = [arm for arm in ("oldest", "active") if f"{arm}_{seed}" not in arm_seconds]
        if not todo:
            print(f"  seed {seed}: both arms already in {args.out.with_suffix('.json')}, skipped", flush=True)
            continue
        # the screener fills its classes in turn (key-then-treasure episodes come last), so the
        # pool is played in a seeded random order: "oldest first" is then a uniform sample
        order = np.arange(len(pool)) if args.screener_order else np.random.default_rng(seed).permutation(len(pool))
        shuffled = pool.subset(order)
        pool_bag = write_dataset_bag(shuffled, work / f"pool_{seed}", include_oracle=False)
        returns = {e: float(shuffled.returns[e]) for e in range(len(shuffled))}
        for arm in todo:
            arm_start = time.monotonic()
            for labels, ckpt, seconds in run_arm(arm, seed, pool_bag, returns, work, args):
                model, _ = load_checkpoint(ckpt, task="key")
                m = evaluate(model, test)
                rows.append({"arm": arm, "seed": seed, "labels": labels, "seconds": round(seconds, 1),
                             "return_mse": m["return_mse"], "reward_mse": m["reward_mse"],
                             "preference_accuracy": m["preference_accuracy"],
                             "reward_correlation": m["reward_correlation"]})
            arm_seconds[f"{arm}_{seed}"] = time.monotonic() - arm_start
            write_json(args, rows, arm_seconds)
    rows = [r for r in rows if r["seed"] in args.seeds]
    wall = sum(v for k, v in arm_seconds.items() if int(k.split("_")[1]) in args.seeds)
    lines = [f"# Key, pool {args.pool} screened episodes (data seed 1, played in {'the screener' if args.screener_order else 'a random'} order per seed), test {args.test} (data seed 2); "
             f"{args.members}-member CSC ensembles, {args.max_epochs} epochs per version, warm-started; "
             f"a version every {args.batch} labels; seeds {args.seeds}",
             (f"feedback {args.feedback}: a simulated person answering the page's API (pair window "
              f"{args.pair_window}); " if args.feedback == "preferences" else "")
             + "test metrics of the ensemble mean: mean over seeds [worst]",
             f"{'labels':>6}  {'oldest: ' + KEYS[args.feedback][0]:>20} {KEYS[args.feedback][1]:>20}   "
             f"{'active: ' + KEYS[args.feedback][0]:>20} {KEYS[args.feedback][1]:>20}"]
    for labels in sorted({r["labels"] for r in rows}):
        cells = []
        for arm in ("oldest", "active"):
            sel = [r for r in rows if r["arm"] == arm and r["labels"] == labels]
            for key in KEYS[args.feedback]:
                v = np.array([r[key] for r in sel])
                worst = v.min() if key in ("preference_accuracy", "reward_correlation") else v.max()
                cells.append(f"{v.mean():10.4f} [{worst:8.4f}]")
        lines.append(f"{labels:6d}  " + " ".join(cells[:2]) + "   " + " ".join(cells[2:]))
    lines.append(f"# wall time {wall:.0f} s (sum over arms and seeds, this sitting's and earlier ones')")
    text = "\n".join(lines)
    print(text)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".txt").write_text(text + "\n")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9, 3.5))
    for ax, key in zip(axes, KEYS[args.feedback]):
        for arm, colour in (("oldest", "tab:grey"), ("active", "tab:blue")):
            xs = sorted({r["labels"] for r in rows if r["arm"] == arm})
            vals = np.array([[r[key] for r in rows if r["arm"] == arm and r["labels"] == x] for x in xs])
            ax.plot(xs, vals.mean(1), "o-", color=colour, label=f"{arm} first" if arm == "oldest" else
                    "largest disagreement first")
            ax.fill_between(xs, vals.min(1), vals.max(1), color=colour, alpha=0.2)
        if key.endswith("_mse"):
            ax.set_yscale("log")
        ax.set_xlabel("labels given" if args.feedback == "returns" else "comparisons given")
        ax.set_title(f"Key: test {key.replace('_', ' ')}")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(args.out.with_suffix(".png"), dpi=110)
    return 0


if __name__ == "__main__":
    sys.exit(main())
