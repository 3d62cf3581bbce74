"""What the command groups share: option callbacks, help texts, loading a dataset from bags, a
file or a generator, and the one-line summaries they print."""

from __future__ import annotations

from pathlib import Path

import typer

from ..feedback import unknown_feedback


def writable_dir(value: Path | None) -> Path | None:
    """Option callback: an output directory that cannot be written is a one-line error at once."""
    from ..output_paths import check_writable_dir

    if value is not None:
        _option_error(check_writable_dir, value)
    return value


def writable_file(value: Path | None) -> Path | None:
    """Option callback: an output file (or checkpoint stem) that cannot be written, likewise."""
    from ..output_paths import check_writable_file

    if value is not None:
        _option_error(check_writable_file, value)
    return value


def _option_error(check, value) -> None:
    """An option's own check: click names the option in the one-line error ("Invalid value for
    '--out': ..."); every other bad input is translated once, in `nmrm_ros.cli.main`."""
    try:
        check(value)
    except ValueError as exc:
        raise typer.BadParameter(str(exc)) from None


TASK_HELP = ("timer | moving | key | charger | lunar_lander, or your own: gym:<id> | <module>:<attribute> | "
             "lerobot:<dataset dir>")
ORACLE_HELP = ("your own oracle, <module>:<function> or <file.py>:<function> (needed for your own "
               "task; default: the task's own)")


def load_bags(paths: list, task: str | None, labeller: str | None):
    """A dataset from recorded bags, with the validation report printed; (dataset, its DataSource)."""
    from ..bags import load_bag_dataset
    from ..mil.checkpoint import DataSource

    ds, report = load_bag_dataset(list(paths), task=task, labeller=labeller)
    typer.echo(f"bags: {report}")
    return ds, DataSource.bags(paths)


def load_or_generate(data: Path | None, task: str | None, n: int, seed: int):
    """A dataset from an .npz file, or generated (screened task / toy) from task, n and seed;
    (dataset, its DataSource)."""
    from ..datasets import TOY_DATASETS, TrajectoryDataset, generate_screened, make_toy_dataset
    from ..mil.checkpoint import DataSource
    from ..tasks import check_task

    if data is not None:
        if not data.is_file():
            raise typer.BadParameter(f"no dataset file {data}")
        try:
            return TrajectoryDataset.load(data), DataSource.file(data)
        except Exception as exc:  # noqa: BLE001 - any unreadable file: one line, not a traceback
            raise typer.BadParameter(f"{data} is not a dataset .npz (from `nmrm dataset ...`): "
                                     f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}") from None
    if task is None:
        raise typer.BadParameter("give --data FILE or --task")
    if task in TOY_DATASETS:
        return make_toy_dataset(task, n, seed=seed), DataSource.generated(task, n, seed)
    check_task(task)
    return generate_screened(task, n, seed=seed), DataSource.generated(task, n, seed)


def metrics_line(m: dict) -> str:
    """Test metrics in one line: the two MSEs (where return labels exist), then those that do not
    depend on the returns' offset and scale."""
    parts = []
    if m["return_mse"] == m["return_mse"]:  # not NaN: some bags have return labels
        parts.append(f"return MSE {m['return_mse']:.4f}")
    parts.append(f"reward MSE {m['reward_mse']:.5f}")
    if m.get("preference_pairs"):
        parts.append(f"preference accuracy {m['preference_accuracy']:.3f} ({m['preference_pairs']} pairs)")
    if m.get("comparisons"):
        parts.append(f"comparison accuracy {m['comparison_accuracy']:.3f} ({m['comparisons']} comparisons)")
    if m.get("reward_correlation") == m.get("reward_correlation"):
        parts.append(f"reward correlation {m['reward_correlation']:.3f} "
                     f"(centred per step index {m['reward_correlation_centred']:.3f})")
    return ", ".join(parts) + f" ({m['bags']} bags)"


def dataset_summary(ds) -> str:
    import numpy as np

    meta = ds.meta
    returns = ds.returns[np.isfinite(ds.returns)]
    lines = [f"{ds.task}: {len(ds)} trajectories, state size {ds.state_size}, "
             + (f"return mean {returns.mean():.3f} std {returns.std():.3f} "
                f"min {returns.min():.3f} max {returns.max():.3f}" if len(returns) else "no return labels")
             + (f", {len(ds.preferences)} comparisons" if ds.preferences is not None else "")]
    if meta.get("generator") == "return_screening":
        lines.append(f"  {meta['pool']} episodes rolled out ({meta['policy']} policy, seed {meta['seed']}) in "
                     f"{meta['seconds']:.2f} s; at most {meta['cap_per_bin']} per return bin of {meta['bins']}; "
                     f"lengths {ds.lengths.min()}..{ds.lengths.max()}")
    if "draws" in meta:
        lines.append(f"  drawn {meta['draws']} trajectories in {meta.get('seconds', float('nan')):.2f} s "
                     f"(seed {meta.get('seed')})")
    if ds.classes is not None:
        lines.append(f"  classes used: {len(np.unique(ds.classes))}")
    return "\n".join(lines)


FEEDBACK_HELP = ("the labels written: returns (one per episode) | preferences (pairwise comparisons "
                 "of a simulated teacher, no returns) | both")
FEEDBACK_OPT = typer.Option("returns", help=FEEDBACK_HELP)
PAIRS_OPT = typer.Option(None, min=1, help="with --feedback preferences|both: comparisons to ask "
                                           "(default: as many as episodes)")
BETA_OPT = typer.Option(float("inf"), min=0.0, help="teacher rationality: P(a better) = sigmoid(beta (R_a - R_b)); "
                                         "inf: always the better one")
MISTAKE_OPT = typer.Option(0.0, min=0.0, max=1.0, help="teacher: probability of flipping an answer")
EQUAL_OPT = typer.Option(0.0, min=0.0, help="teacher: returns this close are 'equal'")
GAMMA_OPT = typer.Option(1.0, min=0.0, max=1.0, help="teacher myopia in (0, 1]: step t weighs gamma^(len - 1 - t)")
SKIP_OPT = typer.Option(float("-inf"), help="teacher: no answer when both returns are below this")


def check_teacher(feedback: str, pairs, beta, mistake, equal, gamma, skip) -> None:
    """The feedback options checked before any episode is rolled out."""
    from ..datasets.preference_teacher import SimulatedTeacher

    if unknown_feedback(feedback, "--feedback"):
        raise typer.BadParameter(unknown_feedback(feedback, "--feedback"))
    if feedback == "returns" and pairs is not None:
        raise typer.BadParameter("--pairs needs --feedback preferences or both")
    SimulatedTeacher(beta=beta, mistake=mistake, equal=equal, gamma=gamma, skip=skip).check()


def with_teacher(ds, feedback: str, pairs: int | None, seed: int, **knobs):
    """`ds` with a simulated teacher's comparisons if feedback asks for them (seeded by `seed`)."""
    from ..datasets.preference_teacher import SimulatedTeacher, with_preferences

    teacher = SimulatedTeacher(**knobs).check()
    if feedback == "returns":
        return ds
    out = with_preferences(ds, pairs or len(ds), teacher, seed)
    typer.echo(f"  teacher {teacher.to_dict()}: {len(out.preferences)} of {pairs or len(ds)} "
               f"comparisons answered")
    return out
