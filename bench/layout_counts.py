"""How many places each of issue 52's concerns is written in, at a commit (default HEAD): the
before/after table of the refactor, counted from the source with `git grep`.

    .venv/bin/python bench/layout_counts.py 93e05ab HEAD
"""

from __future__ import annotations

import argparse
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

#: (concern, what is counted, git grep -E pattern, pathspecs); a count is matching lines (-c summed)
COUNTS = [
    ("forward", "branches on an architecture's name in the model code",
     r'architecture (==|!=|in|not in) *[\("]|arch (==|!=|in) *[\("]', ["nmrm_ros/mil/*.py", ":!nmrm_ros/mil/architectures.py"]),
    ("life", "hand-built checkpoint writers (save_checkpoint calls, torch.save of a model)",
     r"save_checkpoint\(|torch\.save\(", ["nmrm_ros/*.py", "bench/*.py", ":!nmrm_ros/mil/checkpoint.py"]),
    ("life", "a data source string parsed back", r'source\.split\(":"\)|source\[5:\]', ["nmrm_ros/*.py", "bench/*.py"]),
    ("node", "nodes declaring their own exit_code / main / parameters",
     r"self\.exit_code = None|declare_parameters\(self|return run_node\(", ["nmrm_ros/nodes/*.py"]),
    ("node", "protocol read back with getattr", r"getattr\(node, \"[a-z]", ["nmrm_ros/ros/*.py"]),
    ("task", "branches on a task's name outside nmrm_ros/tasks/",
     r'(==|!=| in | not in )\s*\(?\s*"(timer|moving|key|charger|lunar_lander)"|"(timer|moving|key|charger|lunar_lander)"\s*(==|!=)',
     ["nmrm_ros/*.py", ":!nmrm_ros/tasks/*"]),
    ("bench", "bench scripts importing another bench script or tests/",
     r'^\s*from (reproduce_tables|run_cache|any_dataset|preferences|lunar_lander_rewards) import|sys\.path\.insert\(0, str\(REPO / "tests"\)\)',
     ["bench/*.py"]),
    ("cli", "per-command error translations in the command line",
     r"_bad_input\(|BadParameter\(str\(exc\)\)", ["nmrm_ros/cli.py", "nmrm_ros/cli/*.py"]),
]


def count(rev: str, pattern: str, paths: list) -> int:
    res = subprocess.run(["git", "grep", "-c", "-E", pattern, rev, "--", *paths], cwd=REPO,
                         capture_output=True, text=True)
    return sum(int(line.rsplit(":", 1)[1]) for line in res.stdout.splitlines() if line.strip())


def lines_of(rev: str, path: str) -> str:
    files = subprocess.run(["git", "ls-tree", "-r", "--name-only", rev, "--", path], cwd=REPO,
                           capture_output=True, text=True).stdout.split()
    sizes = [len(subprocess.run(["git", "show", f"{rev}:{f}"], cwd=REPO, capture_output=True,
                                text=True).stdout.splitlines()) for f in files if f.endswith(".py")]
    return f"{len(sizes)} file(s), largest {max(sizes) if sizes else 0} lines"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("revs", nargs="*", default=["HEAD"], help="commits to count at (e.g. 93e05ab HEAD)")
    args = parser.parse_args()
    for rev in args.revs:
        if subprocess.run(["git", "rev-parse", "--verify", "-q", f"{rev}^{{commit}}"], cwd=REPO,
                          capture_output=True).returncode:
            raise SystemExit(f"layout_counts: {rev!r} is not a commit of this repository")
    width = max(len(what) for _, what, _, _ in COUNTS)
    print(f"{'concern':8s} {'what':{width}s} " + " ".join(f"{r[:10]:>10s}" for r in args.revs))
    for concern, what, pattern, paths in COUNTS:
        print(f"{concern:8s} {what:{width}s} " + " ".join(f"{count(r, pattern, paths):10d}" for r in args.revs))
    print(f"{'cli':8s} {'the command line (nmrm_ros/cli.py or cli/)':{width}s} "
          + " ".join(f"{lines_of(r, 'nmrm_ros/cli.py') if count(r, '.', ['nmrm_ros/cli.py']) else lines_of(r, 'nmrm_ros/cli')}"
                     for r in args.revs))


if __name__ == "__main__":
    main()
