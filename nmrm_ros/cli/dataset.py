"""`nmrm dataset screen|generate|toy`: labelled trajectory datasets."""

from __future__ import annotations

from pathlib import Path

import typer

from .app import app
from .common import (TASK_HELP, ORACLE_HELP, FEEDBACK_OPT, PAIRS_OPT, BETA_OPT, MISTAKE_OPT,
                     EQUAL_OPT, GAMMA_OPT, SKIP_OPT, writable_dir, writable_file,
                     dataset_summary, check_teacher, with_teacher)


dataset_app = typer.Typer(help="Generate labelled trajectory datasets (screened tasks, toy bags).",
                          no_args_is_help=True)
app.add_typer(dataset_app, name="dataset")



def _screened(task: str, n: int, seed: int, oracle: str, key_fourth_class: bool, pool_size: int | None,
              bins: int, policy: Path | None = None):
    """The screened dataset the dataset commands write (see datasets.generate_screened)."""
    from tqdm import tqdm

    from ..datasets import generate_screened
    from ..tasks import task_info

    screening = task_info(task).screening
    if policy and (oracle or screening != "classes"):  # the dataset code takes the loaded agent
        from ..rl.agent_episodes import AgentEpisodes, load_screening_policy

        policy = AgentEpisodes(policy) if screening == "pool" and not oracle else \
            load_screening_policy(str(policy), task, seed)
    kwargs: dict = {"pool_size": pool_size, "bins": bins, "policy": policy or None}
    if oracle or screening == "return_bins":
        bar = tqdm(total=pool_size or 4 * n, desc=f"rolling out {task}", unit="ep", leave=False, disable=None)
        kwargs["progress"] = lambda done: bar.update(done - bar.n)
    elif screening == "classes":
        kwargs["key_fourth_class"] = key_fourth_class
        bar = tqdm(total=n, desc=f"screening {task}", unit="traj", leave=False, disable=None)
        kwargs["progress"] = lambda kept, examined: (bar.update(kept - bar.n),
                                                     bar.set_postfix(draws=examined))
    return generate_screened(task, n, seed=seed, oracle=oracle, **kwargs)


#: the screening options `dataset screen` and `dataset generate` share
KEY_FOURTH_CLASS_OPT = typer.Option(False, help="Key: also screen treasure_no_key")
POOL_SIZE_OPT = typer.Option(None, min=1, help="episodes rolled out to screen from (lunar_lander: default 2n; "
                                               "your own task or oracle: 4n)")
BINS_OPT = typer.Option(10, min=1, max=1000, help="your own task or oracle: return bins balanced")
POLICY_OPT = typer.Option(None, help="your own task or oracle: a policy.zip of plain states whose episodes are "
                                     "screened (default: uniform random); lunar_lander: an oracle agent's "
                                     "policy.zip whose episodes make a fifth of the pool (the paper's recycled "
                                     "episodes)")


@dataset_app.command("screen")
def dataset_screen(
    task: str = typer.Option(..., help=TASK_HELP),
    n: int = typer.Option(5000, min=1, help="trajectories to keep"),
    seed: int = typer.Option(0, min=0, help="seed of the simulator and the policy"),
    out: Path = typer.Option(None, help="write the dataset here (.npz)", callback=writable_file),
    oracle: str = typer.Option("", help=ORACLE_HELP),
    key_fourth_class: bool = KEY_FOURTH_CLASS_OPT, pool_size: int = POOL_SIZE_OPT, bins: int = BINS_OPT,
    policy: Path = POLICY_OPT,
    feedback: str = FEEDBACK_OPT, pairs: int = PAIRS_OPT, beta: float = BETA_OPT,
    mistake: float = MISTAKE_OPT, equal: float = EQUAL_OPT, gamma: float = GAMMA_OPT,
    skip: float = SKIP_OPT,
) -> None:
    """Generate a screened dataset (paper App. D.2; your own task: balanced return bins) and
    print draws and time; --feedback preferences adds a simulated teacher's comparisons (the
    return labels stay in the .npz as the ground truth; `nmrm train --feedback` chooses)."""
    check_teacher(feedback, pairs, beta, mistake, equal, gamma, skip)
    ds = _screened(task, n, seed, oracle, key_fourth_class, pool_size, bins, policy)
    typer.echo(dataset_summary(ds))
    ds = with_teacher(ds, feedback, pairs, seed, beta=beta, mistake=mistake, equal=equal, gamma=gamma, skip=skip)
    if out is not None:
        typer.echo(f"wrote {ds.save(out)}")


@dataset_app.command("generate")
def dataset_generate(
    task: str = typer.Option(..., help=TASK_HELP),
    episodes: int = typer.Option(..., min=1, help="number of screened episodes to write"),
    out: Path = typer.Option(..., help="bag directory to create", callback=writable_dir),
    seed: int = typer.Option(0, min=0, help="seed of the simulator and the policy"),
    oracle: str = typer.Option("", help=ORACLE_HELP),
    key_fourth_class: bool = KEY_FOURTH_CLASS_OPT, pool_size: int = POOL_SIZE_OPT, bins: int = BINS_OPT,
    policy: Path = POLICY_OPT,
    feedback: str = FEEDBACK_OPT, pairs: int = PAIRS_OPT, beta: float = BETA_OPT,
    mistake: float = MISTAKE_OPT, equal: float = EQUAL_OPT, gamma: float = GAMMA_OPT,
    skip: float = SKIP_OPT,
) -> None:
    """Screened episodes written as a bag with the live graph's topics (observations, actions,
    oracle ground truth, oracle labels); --feedback preferences: a simulated teacher's
    TrajectoryPreference messages instead of return labels (both: both)."""
    import time

    from ..bags import write_dataset_bag

    check_teacher(feedback, pairs, beta, mistake, equal, gamma, skip)
    ds = _screened(task, episodes, seed, oracle, key_fourth_class, pool_size, bins, policy)
    typer.echo(dataset_summary(ds))
    ds = with_teacher(ds, feedback, pairs, seed, beta=beta, mistake=mistake, equal=equal, gamma=gamma, skip=skip)
    perfect = beta == float("inf") and mistake == 0 and equal == 0 and gamma == 1
    t0 = time.perf_counter()
    try:
        write_dataset_bag(ds, out, returns=feedback != "preferences",
                          preference_labeller=f"{'oracle' if perfect else 'teacher'}/{ds.task}")
    except FileExistsError as exc:
        raise typer.BadParameter(str(exc)) from None
    typer.echo(f"wrote {out} ({time.perf_counter() - t0:.1f} s)")


@dataset_app.command("toy")
def dataset_toy(
    name: str = typer.Option(..., help="toggle_switch | push_switch | dial"),
    n: int = typer.Option(5000, min=1, help="number of bags"),
    seed: int = typer.Option(0, min=0),
    out: Path = typer.Option(None, help="write the dataset here (.npz)", callback=writable_file),
) -> None:
    """Generate a toy MIL dataset (paper App. C)."""
    from ..datasets import make_toy_dataset

    ds = make_toy_dataset(name, n, seed=seed)
    typer.echo(dataset_summary(ds))
    if out is not None:
        typer.echo(f"wrote {ds.save(out)}")


