"""Agents a user can trust (issue 50): the runs that collapsed before, run again at HEAD.

    .venv/bin/python bench/agent_trust.py            # every case not run yet, then the table
    .venv/bin/python bench/agent_trust.py --report   # the table of what is there

Each case is a run of `nmrm loop` (rounds 1 = one offline model of screened random episodes)
whose agent collapsed with the agents of 93e05ab (bench/results/reward_model_loop/: final oracle
return and greedy policy then). At HEAD the agent clips its targets to the value bound and keeps
its best policy (docs/guide/agents.md): the table shows, for the same command, the final oracle
return (mean of the last 50 training episodes), the greedy oracle return of the kept policy
(policy.zip, on the model it acted on) and of the last policy (last_policy.zip, on the last
model), and the run's collapse report. 50 greedy episodes, seeds 10^8...

Resumes: a case whose loop.json is in --work (default runs/trust) is not run again; the table is
written to bench/results/agent_trust/table.txt.
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results" / "agent_trust"
BEFORE = ROOT / "bench" / "results" / "reward_model_loop"

#: name -> (task, rounds, labels per round, seed); the name is bench/reward_model_loop.py's
CASES = {
    "key_offline_2000_s0": ("key", 1, 2000, 0),
    "key_loop_1000_s1": ("key", 4, 250, 1),
    "charger_loop_2000_s2": ("charger", 4, 500, 2),
}


def run_case(name: str, work: Path) -> dict:
    from nmrm_ros.rl import evaluate_agent
    from nmrm_ros.rl.reward_model_loop import run_loop

    task, rounds, per_round, seed = CASES[name]
    out = work / name
    if not (out / "loop.json").is_file():
        run_loop(task, rounds, per_round, seed=seed, out=out, log=print)
    loop = json.loads((out / "loop.json").read_text())
    agent = json.loads((out / "agent" / "agent.json").read_text())
    last_model = loop["rounds"][-1]["checkpoint"]
    kept_model = loop.get("kept_checkpoint") or agent.get("checkpoint") or last_model  # the model it acted on
    res = {"case": name, "task": task, "rounds": rounds, "labels_per_round": per_round, "seed": seed,
           "kept_checkpoint": kept_model}
    for policy, checkpoint in (("policy", kept_model), ("last_policy", last_model)):
        path = out / "agent" / f"{policy}.zip"
        if not path.is_file():  # the last policy is the kept one
            path = out / "agent" / "policy.zip"
        res[f"greedy_{policy}"] = float(evaluate_agent(path, task, checkpoint=checkpoint).returns.mean())
    res.update(final=loop["final_oracle_return"], seconds=loop["seconds"], collapse=agent["collapse"],
               kept_policy={k: agent["kept_policy"][k] for k in ("episode", "is_last", "score", "best_score")})
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / f"{name}.json").write_text(json.dumps(res, indent=1))
    return res


def report() -> str:
    lines = ["# bench/agent_trust.py: runs whose agents collapsed at 93e05ab, the same `nmrm loop` command at HEAD",
             "# before: final oracle return / greedy (bench/results/reward_model_loop/); HEAD: final / greedy of the "
             "kept policy (policy.zip) / greedy of the last policy (last_policy.zip); 50 greedy episodes",
             f"{'case':22s} {'before':>15s} {'HEAD final':>10s} {'kept':>7s} {'last':>7s}  collapse report"]
    for name, (task, rounds, per_round, seed) in CASES.items():
        path = RESULTS / f"{name}.json"
        if not path.is_file():
            continue
        r = json.loads(path.read_text())
        before = json.loads((BEFORE / f"{name}.json").read_text()) if (BEFORE / f"{name}.json").is_file() else {}
        b = f"{before.get('final_oracle_return', float('nan')):6.1f} / {before.get('greedy_oracle_return', float('nan')):5.1f}"
        lines.append(f"{name:22s} {b:>15s} {r['final']:10.1f} {r['greedy_policy']:7.1f} {r['greedy_last_policy']:7.1f}  "
                     f"{r['collapse']['summary']}")
        lines.append(f"{'':22s} command: nmrm loop --task {task} --rounds {rounds} --labels-per-round {per_round} "
                     f"--seed {seed} ({r['seconds']:.0f} s)")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cases", nargs="*", default=list(CASES), choices=list(CASES))
    parser.add_argument("--work", type=Path, default=ROOT / "runs" / "trust")
    parser.add_argument("--report", action="store_true")
    args = parser.parse_args()
    if not args.report:
        import torch

        torch.set_num_threads(1)
        for name in args.cases:
            if not (RESULTS / f"{name}.json").is_file():
                run_case(name, args.work)
    text = report()
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "table.txt").write_text(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
