"""Fault campaign: fuzz bags, inject malformed messages into a running graph, kill and restart nodes.

    source scripts/ros_env.sh && .venv/bin/python bench/fault_campaign.py            # all three parts
    .venv/bin/python bench/fault_campaign.py --parts bags --mutations 400 --seed 1

Prints one row per category: tries, clear errors (one-line BagError / a counted warning),
tracebacks, hangs, silently corrupted results, episodes lost.

- bags: a 40-episode Key bag (dataset seed 0) gets one random mutation per try (flip a byte, set
  a run of bytes to random values, truncate) at a random offset; then `load_bag_dataset` (what
  `nmrm train --bag` reads). A result that loads but differs from the original episodes is
  "silently corrupted". Then `repair_bag` and a load: episodes lost = originals not recovered.
- messages: one graph (`nmrm launch`, oracle mode, env_sim with action_timeout 0.5 s, 2 retries);
  malformed observations (NaN, inf, wrong size, future step, past step, unknown episode without
  step 0) published into it one at a time; episodes lost = env_sim's abandoned episodes.
- restarts: env_sim, labeller, reward model and agent as separate processes with config/graph.yaml's
  env_sim settings (action_timeout 5 s, 3 re-publications, wait_for_labels); `kill -9` of one
  (reward_model, labeller_oracle, agent in turn) mid-episode and an immediate restart, N times each.
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
import os
import random
import re
import shutil
import signal
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


class Hang(Exception):
    pass


def _alarm(signum, frame):
    raise Hang()


def row(name: str, tries: int, clear: int, tracebacks: int, hangs: int, corrupted: int, lost: str) -> str:
    return f"| {name} | {tries} | {clear} | {tracebacks} | {hangs} | {corrupted} | {lost} |"


def fuzz_bags(mutations: int, seed: int, timeout: float = 20.0) -> list:
    from nmrm_ros.bags import BagError, load_bag_dataset, repair_bag, write_dataset_bag
    from nmrm_ros.datasets import generate_screened

    rng = random.Random(seed)
    work = Path(tempfile.mkdtemp(prefix="nmrm_fuzz_"))
    ds = generate_screened("key", 40, seed=0)
    original = write_dataset_bag(ds, work / "original")
    data = next(original.glob("*.mcap")).read_bytes()
    signal.signal(signal.SIGALRM, _alarm)
    stats = {"load": [0, 0, 0, 0, 0], "repair": [0, 0, 0, 0, 0]}  # clear, harmless, traceback, hang, corrupted
    lost, examples = [], {}

    def same(back) -> bool:
        return all(np.array_equal(back.states[i], ds.states[e]) and back.returns[i] == ds.returns[e]
                   and back.lengths[i] == ds.lengths[e] for i, e in enumerate(back.meta["episodes"]))

    for i in range(mutations):
        kind = rng.choice(["flip", "run", "truncate"])
        b = bytearray(data)
        at = rng.randrange(8, len(b))
        if kind == "flip":
            b[at] ^= 1 << rng.randrange(8)
        elif kind == "run":
            for j in range(at, min(len(b), at + rng.randrange(2, 64))):
                b[j] = rng.randrange(256)
        else:
            b = b[:at]
        bag = work / f"m{i}"
        shutil.copytree(original, bag)
        (bag / next(original.glob("*.mcap")).name).write_bytes(bytes(b))
        for stage in ("load", "repair"):
            signal.alarm(int(timeout))
            try:
                if stage == "repair":
                    try:
                        repair_bag(bag)
                    except BagError:
                        pass  # nothing readable: a clear error, the bag is left as it was
                back, _ = load_bag_dataset([bag])
                if not same(back):
                    stats[stage][4] += 1
                    examples.setdefault(f"{stage} corrupted", f"{kind} at {at}")
                else:
                    stats[stage][1] += 1
                if stage == "repair":
                    lost.append(len(ds) - len(back))
            except BagError:
                stats[stage][0] += 1
                if stage == "repair":
                    lost.append(len(ds))
            except Hang:
                stats[stage][3] += 1
                examples.setdefault(f"{stage} hang", f"{kind} at {at}")
            except Exception as exc:  # noqa: BLE001 - what we are counting
                stats[stage][2] += 1
                examples.setdefault(f"{stage} traceback", f"{kind} at {at}: {type(exc).__name__}: {exc}")
            finally:
                signal.alarm(0)
        shutil.rmtree(bag, ignore_errors=True)
    shutil.rmtree(work, ignore_errors=True)
    load, rep = stats["load"], stats["repair"]
    rows = [row("bag mutation → load (train's reader)", mutations, load[0], load[2], load[3], load[4],
                f"refused: {load[0]}, unchanged data: {load[1]}"),
            row("bag mutation → repair → load", mutations, rep[0], rep[2], rep[3], rep[4],
                f"episodes lost per bag: median {np.median(lost):.0f}, worst {max(lost)} of {len(ds)}")]
    return rows + [f"  {k}: {v}" for k, v in examples.items()]


def _params(tmp: Path) -> Path:
    import yaml

    params = yaml.safe_load((REPO / "config" / "graph.yaml").read_text())
    params["/**/env_sim"]["ros__parameters"].update({"action_timeout": 0.5, "max_retries": 2})
    path = tmp / "graph.yaml"
    path.write_text(yaml.safe_dump(params))
    return path


def _abandoned(out: str) -> int:
    m = re.search(r"(\d+) episode\(s\) abandoned", out)
    return int(m.group(1)) if m else -1


def inject_messages(n: int, seed: int) -> list:
    from nmrm_ros.testing.graph import Capture, finish, launch

    from nmrm_msgs.msg import EnvObservation
    from nmrm_ros.ros.topics import OBSERVATION

    rng = random.Random(seed)
    os.environ["ROS_DOMAIN_ID"] = str(150 + seed % 50)
    tmp = Path(tempfile.mkdtemp())
    cap = Capture()
    pub = cap.publisher(EnvObservation, OBSERVATION)
    episodes = 3 * n + 20
    proc = launch(f"episodes:={episodes}", f"params:={_params(tmp)}", "wait_for_subscribers:=3")
    kinds = ["nan", "inf", "size", "future", "past", "no_step0"]
    hang = False
    if not cap.spin_until(lambda: len(cap.msgs["observation"]) >= 50, 60):
        hang = True
    injected = 0
    for i in range(n):
        if proc.poll() is not None:
            break  # the graph finished (all its episodes) before every fault was injected
        injected += 1
        cur = cap.msgs["observation"][-1]
        kind = kinds[i % len(kinds)]
        state = [0.5, 0.5]
        step, episode = cur.step, cur.episode
        if kind == "nan":
            state = [float("nan"), 0.5]
        elif kind == "inf":
            state = [0.5, float("inf")]
        elif kind == "size":
            state = [0.5] * rng.choice([1, 3, 5])
        elif kind == "future":
            step = cur.step + rng.randrange(2, 50)
        elif kind == "past":
            step, state = max(0, cur.step - rng.randrange(1, 10)), [rng.random(), rng.random()]
            step = step if step > 0 else 1
        else:
            episode, step = cur.episode + 1000, 5
        pub.publish(EnvObservation(task="key", episode=episode, step=step, state=state))
        before = len(cap.msgs["observation"])
        if not cap.spin_until(lambda b=before: len(cap.msgs["observation"]) >= b + 120
                              or proc.poll() is not None, 60):
            hang = True  # the graph is still running but stalled
            break
    cap.node.destroy_publisher(pub)
    cap.spin_until(lambda: proc.poll() is not None, 300)
    try:
        code, out = finish(proc, 30)
    except AssertionError as exc:
        code, out, hang = -1, str(exc), True
    cap.close()
    tracebacks = out.count("Traceback")
    lost = _abandoned(out)
    labelled = re.findall(r"labelled (\d+) episode", out)
    return [row("malformed observation into a running graph", injected, injected if code == 0 else 0,
                tracebacks, int(hang),
                0, f"{lost} abandoned of {episodes} (exit {code}; labelled {labelled[-1] if labelled else '?'})")]


def kill_restart(times: int, seed: int) -> list:
    from nmrm_ros.testing.graph import Capture, finish, start

    os.environ["ROS_DOMAIN_ID"] = str(100 + seed % 50)
    rows = []
    for victim in ("reward_model", "labeller_oracle", "agent"):
        episodes = 3 * times + 10
        cap = Capture()
        # config/graph.yaml's env_sim settings: action_timeout 5 s, 3 re-publications, labels awaited
        env = start("env_sim", task="key", episodes=episodes, wait_for_subscribers=3,
                    wait_for_nodes="[labeller_oracle, reward_model]", start_delay=1.0,
                    action_timeout=5.0, max_retries=3, wait_for_labels=True)
        args = {"reward_model": dict(mode="oracle", task="key", exit_with_upstream=True),
                "labeller_oracle": dict(task="key", exit_with_upstream=True),
                "agent": dict(task="key", exit_with_upstream=True)}
        procs = {name: start(name, **kw) for name, kw in args.items()}
        hang, tracebacks, outs = False, 0, []
        for k in range(times):
            target = 3 * k + 2
            if not cap.spin_until(lambda t=target: any(m.episode >= t and m.step >= 50
                                                       for m in cap.msgs["observation"][-5:]), 120):
                hang = True
                break
            p = procs[victim]
            p.kill()
            outs.append(p.communicate()[0])
            procs[victim] = start(victim, **args[victim])
        cap.spin_until(lambda: env.poll() is not None, 300)
        try:
            code, out = finish(env, 30)
        except AssertionError as exc:
            code, out, hang = -1, str(exc), True
        for name, p in procs.items():
            try:
                outs.append(finish(p, 30)[1])
            except AssertionError as exc:
                outs.append(str(exc))
                hang = True
        labels = {m.episode for m in cap.msgs["label"]}
        cap.close()
        tracebacks = sum(o.count("Traceback") for o in outs + [out])
        unlabelled = re.search(r"(\d+) without a label", out)
        rows.append(row(f"kill -9 + restart of {victim}", times, times if code == 0 else 0, tracebacks,
                        int(hang), 0, f"{_abandoned(out)} abandoned, {len(labels)} of {episodes} labelled "
                                      f"(env_sim: {unlabelled.group(1) if unlabelled else '?'} without a "
                                      f"label; exit {code})"))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--parts", nargs="*", default=["bags", "messages", "restarts"])
    ap.add_argument("--mutations", type=int, default=200)
    ap.add_argument("--messages", type=int, default=50)
    ap.add_argument("--restarts", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    from nmrm_ros.ros.ament_paths import ensure_ament_prefix_path
    from nmrm_ros.ros.discovery import use_discovery_profile

    ensure_ament_prefix_path()
    use_discovery_profile()
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    t0 = time.perf_counter()
    print(f"# fault campaign, seed {args.seed}")
    print("| category | tries | clear errors / healed | tracebacks | hangs | silently corrupted | episodes lost |")
    print("|---|---|---|---|---|---|---|")
    for part, fn, n in (("bags", fuzz_bags, args.mutations), ("messages", inject_messages, args.messages),
                        ("restarts", kill_restart, args.restarts)):
        if part in args.parts:
            for line in fn(n, args.seed):
                print(line, flush=True)
    print(f"# wall time {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
