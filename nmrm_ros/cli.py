"""The `nmrm` command line: one entry point, one subcommand per job.

Built on typer (click underneath). Heavy imports (torch, rclpy, gymnasium) happen inside the
subcommands, so `nmrm --help` stays fast.
"""

from __future__ import annotations

import signal
import time
from pathlib import Path

import typer

def _output_dir(value: Path | None) -> Path | None:
    """Option callback: an output directory that cannot be written is a one-line error at once."""
    from .output_paths import check_writable_dir

    if value is not None:
        _bad_input(check_writable_dir, value)
    return value


def _output_file(value: Path | None) -> Path | None:
    """Option callback: an output file (or checkpoint stem) that cannot be written, likewise."""
    from .output_paths import check_writable_file

    if value is not None:
        _bad_input(check_writable_file, value)
    return value


app = typer.Typer(
    name="nmrm",
    help="Non-Markovian reward modelling with MIL, served to RL agents over ROS 2.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


@app.callback()
def _root() -> None:
    """Non-Markovian reward modelling with MIL, served to RL agents over ROS 2."""
    from .ros.ament_paths import ensure_ament_prefix_path
    from .ros.discovery import use_discovery_profile

    ensure_ament_prefix_path()  # no `source` needed: our packages know where they are installed
    use_discovery_profile()  # for the nodes `nmrm launch` starts and in-process rclpy


@app.command()
def info() -> None:
    """Print versions and where the ROS 2 packages of this install are found."""
    import os

    import nmrm_ros

    typer.echo(f"nmrm_ros {nmrm_ros.__version__}")
    try:
        from ament_index_python.packages import get_package_prefix

        for pkg in ("nmrm_ros", "nmrm_msgs", "rclpy"):
            typer.echo(f"  {pkg:10s} prefix: {get_package_prefix(pkg)}")
    except Exception as exc:  # noqa: BLE001 - report, don't crash an info command
        typer.echo(f"  ament index: {exc} (AMENT_PREFIX_PATH={os.environ.get('AMENT_PREFIX_PATH')})")
    for mod in ("rclpy", "torch", "gymnasium", "stable_baselines3", "numpy", "mcap"):
        try:
            m = __import__(mod)
            typer.echo(f"  {mod:18s} {getattr(m, '__version__', '(no version)')}")
        except ImportError as exc:
            typer.echo(f"  {mod:18s} missing: {exc}")


dataset_app = typer.Typer(help="Generate labelled trajectory datasets (screened tasks, toy bags).",
                          no_args_is_help=True)
app.add_typer(dataset_app, name="dataset")


TASK_HELP = "timer | moving | key | charger | lunar_lander, or your own: gym:<id> | <module>:<attribute>"
ORACLE_HELP = ("your own oracle, <module>:<function> or <file.py>:<function> (needed for your own "
               "task; default: the task's own)")


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


def _teach_check(feedback: str, pairs, beta, mistake, equal, gamma, skip) -> None:
    """The feedback options checked before any episode is rolled out."""
    from .datasets.preference_teacher import SimulatedTeacher

    if feedback not in ("returns", "preferences", "both"):
        raise typer.BadParameter(f"--feedback must be returns, preferences or both, got {feedback!r}")
    if feedback == "returns" and pairs is not None:
        raise typer.BadParameter("--pairs needs --feedback preferences or both")
    _bad_input(SimulatedTeacher(beta=beta, mistake=mistake, equal=equal, gamma=gamma, skip=skip).check)


def _teach(ds, feedback: str, pairs: int | None, seed: int, **knobs):
    """`ds` with a simulated teacher's comparisons if feedback asks for them (seeded by `seed`)."""
    from .datasets.preference_teacher import SimulatedTeacher, with_preferences

    teacher = _bad_input(SimulatedTeacher(**knobs).check)
    if feedback == "returns":
        return ds
    out = _bad_input(with_preferences, ds, pairs or len(ds), teacher, seed)
    typer.echo(f"  teacher {teacher.to_dict()}: {len(out.preferences)} of {pairs or len(ds)} "
               f"comparisons answered")
    return out


def _screened(task: str, n: int, seed: int, oracle: str, key_fourth_class: bool, pool_size: int | None,
              bins: int, policy: Path | None = None):
    """The screened dataset the dataset commands write (see datasets.generate_screened)."""
    from tqdm import tqdm

    from .datasets import generate_screened
    from .tasks import task_info

    screening = _bad_input(task_info, task).screening
    if policy and (oracle or screening != "classes"):  # the dataset code takes the loaded agent
        from .rl.agent_episodes import AgentEpisodes, load_screening_policy

        policy = AgentEpisodes(policy) if screening == "pool" and not oracle else \
            _bad_input(load_screening_policy, str(policy), task, seed)
    kwargs: dict = {"pool_size": pool_size, "bins": bins, "policy": policy or None}
    if oracle or screening == "return_bins":
        bar = tqdm(total=pool_size or 4 * n, desc=f"rolling out {task}", unit="ep", leave=False, disable=None)
        kwargs["progress"] = lambda done: bar.update(done - bar.n)
    elif screening == "classes":
        kwargs["key_fourth_class"] = key_fourth_class
        bar = tqdm(total=n, desc=f"screening {task}", unit="traj", leave=False, disable=None)
        kwargs["progress"] = lambda kept, examined: (bar.update(kept - bar.n),
                                                     bar.set_postfix(draws=examined))
    return _bad_input(generate_screened, task, n, seed=seed, oracle=oracle, **kwargs)


@dataset_app.command("screen")
def dataset_screen(
    task: str = typer.Option(..., help=TASK_HELP),
    n: int = typer.Option(5000, min=1, help="trajectories to keep"),
    seed: int = typer.Option(0, min=0, help="seed of the simulator and the policy"),
    out: Path = typer.Option(None, help="write the dataset here (.npz)", callback=_output_file),
    oracle: str = typer.Option("", help=ORACLE_HELP),
    key_fourth_class: bool = typer.Option(False, help="Key: also screen treasure_no_key"),
    pool_size: int = typer.Option(None, min=1, help="episodes rolled out to screen from (lunar_lander: "
                                                    "default 2n; your own task or oracle: 4n)"),
    bins: int = typer.Option(10, min=1, max=1000, help="your own task or oracle: return bins balanced"),
    policy: Path = typer.Option(None, help="your own task or oracle: a policy.zip of plain states whose "
                                           "episodes are screened (default: uniform random); lunar_lander: "
                                           "an oracle agent's policy.zip whose episodes make a fifth of "
                                           "the pool (the paper's recycled episodes)"),
    feedback: str = FEEDBACK_OPT, pairs: int = PAIRS_OPT, beta: float = BETA_OPT,
    mistake: float = MISTAKE_OPT, equal: float = EQUAL_OPT, gamma: float = GAMMA_OPT,
    skip: float = SKIP_OPT,
) -> None:
    """Generate a screened dataset (paper App. D.2; your own task: balanced return bins) and
    print draws and time; --feedback preferences adds a simulated teacher's comparisons (the
    return labels stay in the .npz as the ground truth; `nmrm train --feedback` chooses)."""
    _teach_check(feedback, pairs, beta, mistake, equal, gamma, skip)
    ds = _screened(task, n, seed, oracle, key_fourth_class, pool_size, bins, policy)
    typer.echo(_dataset_summary(ds))
    ds = _teach(ds, feedback, pairs, seed, beta=beta, mistake=mistake, equal=equal, gamma=gamma, skip=skip)
    if out is not None:
        typer.echo(f"wrote {ds.save(out)}")


@dataset_app.command("generate")
def dataset_generate(
    task: str = typer.Option(..., help=TASK_HELP),
    episodes: int = typer.Option(..., min=1, help="number of screened episodes to write"),
    out: Path = typer.Option(..., help="bag directory to create", callback=_output_dir),
    seed: int = typer.Option(0, min=0, help="seed of the simulator and the policy"),
    oracle: str = typer.Option("", help=ORACLE_HELP),
    key_fourth_class: bool = typer.Option(False, help="Key: also screen treasure_no_key"),
    pool_size: int = typer.Option(None, min=1, help="episodes rolled out to screen from (lunar_lander: "
                                                    "default 2n; your own task or oracle: 4n)"),
    bins: int = typer.Option(10, min=1, max=1000, help="your own task or oracle: return bins balanced"),
    policy: Path = typer.Option(None, help="your own task or oracle: a policy.zip of plain states whose "
                                           "episodes are screened (default: uniform random); lunar_lander: "
                                           "an oracle agent's policy.zip whose episodes make a fifth of "
                                           "the pool (the paper's recycled episodes)"),
    feedback: str = FEEDBACK_OPT, pairs: int = PAIRS_OPT, beta: float = BETA_OPT,
    mistake: float = MISTAKE_OPT, equal: float = EQUAL_OPT, gamma: float = GAMMA_OPT,
    skip: float = SKIP_OPT,
) -> None:
    """Screened episodes written as a bag with the live graph's topics (observations, actions,
    oracle ground truth, oracle labels); --feedback preferences: a simulated teacher's
    TrajectoryPreference messages instead of return labels (both: both)."""
    import time

    from .bags import write_dataset_bag

    _teach_check(feedback, pairs, beta, mistake, equal, gamma, skip)
    ds = _screened(task, episodes, seed, oracle, key_fourth_class, pool_size, bins, policy)
    typer.echo(_dataset_summary(ds))
    ds = _teach(ds, feedback, pairs, seed, beta=beta, mistake=mistake, equal=equal, gamma=gamma, skip=skip)
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
    out: Path = typer.Option(None, help="write the dataset here (.npz)", callback=_output_file),
) -> None:
    """Generate a toy MIL dataset (paper App. C)."""
    from .datasets import make_toy_dataset

    ds = _bad_input(make_toy_dataset, name, n, seed=seed)
    typer.echo(_dataset_summary(ds))
    if out is not None:
        typer.echo(f"wrote {ds.save(out)}")


@app.command()
def demo(
    task: str = typer.Option("key", help="navigation task"),
    live_episodes: int = typer.Option(30, min=1, help="episodes collected with the live graph"),
    screened: int = typer.Option(1500, min=1, help="screened episodes generated in-process"),
    epochs: int = typer.Option(100, min=1, help="max training epochs"),
    agent_episodes: int = typer.Option(150, min=1, help="episodes of the DQN agent trained through the graph"),
    seed: int = typer.Option(0, min=0, help="seed of data, split, weights and agent"),
    out: Path = typer.Option(Path("runs/demo"), help="output directory (replaced)", callback=_output_dir),
) -> None:
    """The main job, end to end on a small task (nmrm_ros/demo.py): collect episodes with the live
    graph, generate screened ones, train a CSC LSTM reward model from the bags, serve it on a replay
    and compare with the oracle, then train a DQN agent through the graph on the served reward and
    judge its greedy policy by the oracle against a random policy."""
    from .demo import DemoError, run_demo
    from .tasks import NAVIGATION_TASKS, task_info

    if not _bad_input(task_info, task).navigation:
        raise typer.BadParameter(f"the demo runs a navigation task {NAVIGATION_TASKS}, not {task!r}")
    try:
        run_demo(task, live_episodes, screened, epochs, agent_episodes, seed, out, echo=typer.echo)
    except DemoError as exc:
        typer.echo(f"demo failed: {exc}", err=True)
        raise typer.Exit(1) from None


@app.command(context_settings={"allow_extra_args": True, "ignore_unknown_options": True})
def launch(
    ctx: typer.Context,
    file: Path = typer.Argument(..., help="a ROS 2 YAML launch file (see nmrm_ros/launcher.py)"),
    grace: float = typer.Option(10.0, min=0.0, help="seconds between SIGINT and SIGTERM when stopping"),
) -> None:
    """Run a launch file's nodes as separate processes; extra NAME:=VALUE set launch arguments."""
    from .launcher import LaunchError, parse_launch_file, run

    arguments = {}
    for item in ctx.args:
        if ":=" not in item:
            raise typer.BadParameter(f"launch arguments are NAME:=VALUE, got {item!r}")
        name, value = item.split(":=", 1)
        arguments[name] = value
    try:
        nodes = parse_launch_file(file, arguments)
    except LaunchError as exc:
        raise typer.BadParameter(str(exc)) from None
    raise typer.Exit(run(nodes, grace=grace))


@app.command()
def fleet(
    robots: int = typer.Option(2, min=1, help="number of robots (namespaces /robot1 ... /robotN)"),
    task: str = typer.Option("key", help="timer | moving | key | charger | lunar_lander"),
    episodes: int = typer.Option(100, min=1, help="episodes per robot (the learner learns from robots x episodes)"),
    mode: str = typer.Option("oracle", help="reward of every robot's reward_model: oracle | model"),
    checkpoint: Path = typer.Option(None, help="MIL checkpoint for mode model"),
    seed: int = typer.Option(0, min=0, help="agent seed; robot i's episodes start from seed + i * 100000"),
    out: Path = typer.Option(Path("runs/fleet"), help="output: OUT/policy (the learner) and OUT/bag (all robots)",
                             callback=_output_dir),
    save_every: int = typer.Option(50, min=1, help="save the policy every this many fleet episodes"),
    learning_starts: int = typer.Option(-1, min=-1, help="random steps before learning (-1: config/rl.yaml)"),
    save_replay_buffer: bool = typer.Option(False, help="also save OUT/policy/replay_buffer.pkl"),
    grace: float = typer.Option(10.0, min=0.0, help="seconds between SIGINT and SIGTERM when stopping"),
) -> None:
    """N namespaced robot graphs (env_sim, reward_model, labeller) and one learner that trains one
    policy from all of them, with one recorder for the fleet (launch_scripts/fleet_*.launch.yaml)."""
    from .fleet import run_fleet
    from .launcher import LaunchError
    from .mil import CheckpointError, load_checkpoint

    if mode not in ("oracle", "model"):
        raise typer.BadParameter(f"--mode must be oracle or model, got {mode!r}")
    if mode == "model":
        if checkpoint is None:
            raise typer.BadParameter("--mode model needs --checkpoint")
        try:
            load_checkpoint(checkpoint)
        except CheckpointError as exc:
            raise typer.BadParameter(str(exc)) from None
    try:
        code = run_fleet(robots, grace=grace, task=task, episodes=episodes, out=out, mode=mode,
                         checkpoint=checkpoint or "", seed=seed, save_every=save_every,
                         learning_starts=learning_starts, save_replay_buffer=save_replay_buffer)
    except LaunchError as exc:
        raise typer.BadParameter(str(exc)) from None
    raise typer.Exit(code)


labels_app = typer.Typer(help="Labels: who gave which, how far people agree, export and import.",
                         no_args_is_help=True)
app.add_typer(labels_app, name="labels")


def _label_records(bag: list | None, checkpoint: Path | None, file: Path | None) -> list:
    """Label records from exactly one kind of source (bags, a checkpoint's provenance, a file)."""
    from .bags import BagError
    from .labelling.label_files import checkpoint_labels, read_bag_labels, read_labels
    from .mil import CheckpointError

    given = [x for x in (bag, checkpoint, file) if x]
    if len(given) != 1:
        raise typer.BadParameter("give labels bags (--bag), a checkpoint (--checkpoint) or a file (--file)")
    try:
        if bag:
            return read_bag_labels(bag)
        if checkpoint:
            return checkpoint_labels(checkpoint)
        return read_labels(file)
    except (BagError, CheckpointError, ValueError) as exc:
        raise typer.BadParameter(str(exc)) from None


def _optional_labels(checkpoint: Path) -> list:
    """A checkpoint's return labels, or [] if it was trained on comparisons only."""
    from .labelling.label_files import checkpoint_labels

    try:
        return [r for r in checkpoint_labels(checkpoint) if r.get("return") is not None]
    except ValueError:
        return []


@labels_app.command("report")
def labels_report(
    bag: list[Path] = typer.Option(None, help="labels bags or recordings (repeat for several)"),
    checkpoint: Path = typer.Option(None, help="a checkpoint: the labels it was built from"),
    file: Path = typer.Option(None, help="a labels file (.jsonl or .csv)"),
    show: bool = typer.Option(False, help="also list every label (latest per labeller and episode)"),
) -> None:
    """Who labelled how much, each person's error on gold episodes (labels of gold/ or oracle/
    labellers), and how far people agree on the episodes they both labelled; the same for
    comparisons (TrajectoryPreference) in bags and checkpoints."""
    from .labelling.agreement import comparison_report, format_comparison_report, format_report, label_report
    from .labelling.label_files import checkpoint_comparisons, latest, read_bag_comparisons

    comparisons = _bad_input(lambda: read_bag_comparisons(bag) if bag else
                             checkpoint_comparisons(checkpoint) if checkpoint else [])
    records = _label_records(bag, checkpoint, file) if not (comparisons and checkpoint) else \
        _bad_input(_optional_labels, checkpoint)
    if not records and not comparisons:
        raise typer.BadParameter("no labels there")
    if records:
        for line in format_report(label_report(records)):
            typer.echo(line)
    if comparisons:
        for line in format_comparison_report(comparison_report(comparisons)):
            typer.echo(line)
    if show:
        typer.echo(f"{'labeller':24s} {'source':10s} {'episode':>8s} {'length':>6s} {'return':>10s}  given (UTC)")
        for r in sorted(latest(records), key=lambda r: (r["source"], r["episode"], r["labeller"])):
            when = time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime(r["stamp_ns"] / 1e9))
            typer.echo(f"{r['labeller']:24s} {r['source'] or '-':10s} {r['episode']:8d} {r['length']:6d} "
                       f"{r['return']:10.4g}  {when}")


@labels_app.command("export")
def labels_export(
    bag: list[Path] = typer.Option(None, help="labels bags or recordings (repeat for several)"),
    checkpoint: Path = typer.Option(None, help="a checkpoint: the labels it was built from"),
    out: Path = typer.Option(..., help="the file to write: .jsonl (JSON lines) or .csv", callback=_output_file),
    every: bool = typer.Option(False, "--all", help="every label given, corrections too (default: the latest per labeller and episode)"),
) -> None:
    """Write labels to a plain file (fields: task, source, episode, length, return, labeller, stamp_ns)."""
    from .labelling.label_files import SUFFIXES, latest, write_labels

    if out.suffix.lower() not in SUFFIXES:
        raise typer.BadParameter(f"--out must end in .jsonl or .csv, got {out.name!r}")
    records = _label_records(bag, checkpoint, None)
    records = records if every else latest(records)
    write_labels(records, out)
    typer.echo(f"wrote {len(records)} label(s) to {out}")


@labels_app.command("import")
def labels_import(
    file: Path = typer.Option(..., help="a labels file (.jsonl or .csv), as `nmrm labels export` writes"),
    out: Path = typer.Option(..., help="the labels-only bag to create", callback=_output_dir),
) -> None:
    """Turn a labels file into a labels-only bag, which `nmrm train --bag RECORDING --bag OUT` joins
    to its recording (and the trainer node reads with `bags`)."""
    from .labelling.label_files import write_labels_bag

    if out.exists() and any(out.iterdir()):
        raise typer.BadParameter(f"--out {out} exists and is not empty")
    records = _label_records(None, None, file)
    if not records:
        raise typer.BadParameter(f"{file}: no labels")
    write_labels_bag(records, out)
    typer.echo(f"wrote {len(records)} label(s) to the labels bag {out}")


bag_app = typer.Typer(help="Inspect and repair MCAP bags.", no_args_is_help=True)
app.add_typer(bag_app, name="bag")


@bag_app.command("info")
def bag_info(path: Path = typer.Argument(..., help="bag directory or .mcap file")) -> None:
    """Topics, types and message counts of a bag, and its episodes."""
    from .bags import BagError, bag_summary, iter_raw, load_bag_dataset

    try:
        summary = bag_summary(path)
        for topic, (type_name, count) in summary.items():
            typer.echo(f"{topic:28s} {type_name:34s} {count:8d}")
        sum(1 for _ in iter_raw(path))  # every chunk read and its CRC checked
    except BagError as exc:
        raise typer.BadParameter(str(exc)) from None
    try:
        _, report = load_bag_dataset([path])
        typer.echo(f"episodes: {report}")
    except BagError as exc:
        typer.echo(f"episodes: {exc}")


@bag_app.command("repair")
def bag_repair(path: Path = typer.Argument(..., help="bag directory (or .mcap) of a killed recording")) -> None:
    """Rebuild a damaged or killed recording from every intact chunk (original kept beside it)."""
    from .bags import BagError, load_bag_dataset, repair_bag

    try:
        report = repair_bag(path)
    except BagError as exc:
        raise typer.BadParameter(str(exc)) from None
    typer.echo(f"repaired {report.path}: {report.messages} messages recovered "
               f"({', '.join(f'{t} {n}' for t, n in report.topics.items())}) from "
               f"{report.chunks_kept} intact chunk(s); lost: {report.chunks_lost} damaged chunk(s)"
               f"{f', {report.messages_without_channel} message(s) of unknown channels' if report.messages_without_channel else ''}; "
               f"damage: {report.damaged}; original kept as {report.backup}")
    try:
        _, episodes = load_bag_dataset([report.path])
        typer.echo(f"episodes: {episodes}")
    except BagError as exc:
        typer.echo(f"episodes: {exc}")


def _load_bags(paths: list, task: str | None, labeller: str | None):
    """A dataset from recorded bags, with the validation report printed; (dataset, its DataSource)."""
    from .bags import BagError, load_bag_dataset
    from .mil.checkpoint import DataSource

    try:
        ds, report = load_bag_dataset(list(paths), task=task, labeller=labeller)
    except BagError as exc:
        raise typer.BadParameter(str(exc)) from None
    typer.echo(f"bags: {report}")
    return ds, DataSource.bags(paths)


def _load_or_generate(data: Path | None, task: str | None, n: int, seed: int):
    """A dataset from an .npz file, or generated (screened task / toy) from task, n and seed;
    (dataset, its DataSource)."""
    from .datasets import TOY_DATASETS, TrajectoryDataset, generate_screened, make_toy_dataset
    from .mil.checkpoint import DataSource
    from .tasks import check_task

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
    _bad_input(check_task, task)
    return generate_screened(task, n, seed=seed), DataSource.generated(task, n, seed)


@app.command()
def train(
    task: str = typer.Option(None, help="task or toy dataset to generate data for (if no --data)"),
    data: Path = typer.Option(None, help="a dataset .npz (from `nmrm dataset ...`)"),
    bag: list[Path] = typer.Option(None, help="bag(s) of recorded episodes (repeatable)"),
    labeller: str = typer.Option(None, help="with --bag: whose labels to use if several labelled"),
    arch: str = typer.Option("csc_lstm", help="instance_nn | embedding_lstm | instance_lstm | csc_lstm"),
    out: Path = typer.Option(Path("runs/model"), help="checkpoint path (writes OUT.pt and OUT.json)",
                             callback=_output_file),
    n: int = typer.Option(5000, min=1, help="trajectories to generate (without --data)"),
    data_seed: int = typer.Option(0, min=0, help="seed of the generated data"),
    seed: int = typer.Option(0, min=0, help="seed of the weight initialisation and batch order"),
    split_seed: int = typer.Option(0, min=0, help="seed of the 80/10/10 train/val/test split"),
    epochs: int = typer.Option(None, min=1, help="override max_epochs"),
    lr: float = typer.Option(None, help="override the learning rate"),
    batch_size: int = typer.Option(None, min=1, help="override the batch size"),
    config: Path = typer.Option(None, help="training config YAML (default config/mil_training.yaml)",
                                exists=True, dir_okay=False, readable=True),
    ensemble: int = typer.Option(None, min=1, help="train K models as one ensemble in one pass (seeds SEED..SEED+K-1; "
                                 "served as their mean reward); default: the task's `members` in the config"),
    split_mode: str = typer.Option("shared", help="ensemble splits: shared | bootstrap | per_member"),
    label_swap: float = typer.Option(None, min=0.0, max=1.0, help="label noise: swap this fraction of the training and "
                                     "validation labels between trajectories (paper Sec. 5.2)"),
    reward_l1: float = typer.Option(None, min=0.0, help="override the weight of the L1 sparsity prior on "
                                    "per-step rewards (config/mil_training.yaml; 0: off; not used with "
                                    "--feedback preferences, which leaves the rewards' scale free)"),
    prefix_fraction: float = typer.Option(None, min=0.0, max=1.0, help="cut this fraction of the training and "
                                          "validation episodes at a random step, labelled with the return "
                                          "earned by then (needs the oracle's per-step rewards; default: the "
                                          "task's config)"),
    output_activation: str = typer.Option(None, help="the head's output activation: none | leaky_relu (the "
                                          "paper's, slope 1e-6) | softplus; default: the task's config"),
    feedback: str = typer.Option(None, help="what to learn from: returns (the MSE of episode returns) | "
                                 "preferences (a Bradley-Terry loss on pairwise comparisons) | both; default "
                                 "returns"),
    fe_sizes: str = typer.Option(None, help="feature-extractor layer widths, e.g. 64,32,32; default: the "
                                 "task's config, else the paper's for the task's family"),
    head_sizes: str = typer.Option(None, help="head hidden-layer widths, e.g. 32,16 ('' for none); default: "
                                   "as --fe-sizes"),
) -> None:
    """Train a MIL reward model or an ensemble (early stopping on the validation loss) and
    evaluate it on the test split."""
    from .mil import ARCHITECTURES, load_train_config
    from .mil.pipeline import SPLIT_MODES, fit

    if arch not in ARCHITECTURES:
        raise typer.BadParameter(f"unknown architecture {arch!r}; known: {', '.join(ARCHITECTURES)}")
    if split_mode not in SPLIT_MODES:
        raise typer.BadParameter(f"--split-mode must be one of {', '.join(SPLIT_MODES)}, got {split_mode!r}")
    settings = dict(max_epochs=epochs, lr=lr, batch_size=batch_size, seed=seed, label_swap=label_swap,
                    reward_l1=reward_l1, feedback=feedback, output_activation=output_activation,
                    fe_sizes=fe_sizes, head_sizes=head_sizes, prefix_fraction=prefix_fraction)
    if task:  # the settings are checked before any data is loaded or generated
        _bad_input(load_train_config, task, config, **settings)
    if bag:
        ds, source = _load_bags(bag, task, labeller)
    else:
        ds, source = _load_or_generate(data, task, n, data_seed)
    cfg = _bad_input(load_train_config, ds.task, config, **settings)
    if len(ds) < 10:
        raise typer.BadParameter(f"{len(ds)} trajectories cannot be split 80/10/10 into train, validation "
                                 f"and test sets: give at least 10 (the paper: 5000)")
    if len(ds) < 100:
        typer.echo(f"warning: only {len(ds)} trajectories; the validation and test sets have about "
                   f"{len(ds) // 10} each, so the figures below are noise", err=True)
    compared = 0 if ds.preferences is None else len(ds.preferences)
    typer.echo(f"training {arch} on {ds.task}" + (f" from {cfg.feedback}" if cfg.feedback != "returns" else "")
               + f": {len(ds)} trajectories"
               + (f", {compared} comparisons" if compared else "") + f" ({source}), "
               f"lr {cfg.lr}, batch {cfg.batch_size}, max {cfg.max_epochs} epochs, seed {seed}"
               + (f", {cfg.label_swap:g} of the labels swapped" if cfg.label_swap else ""))
    if cfg.feedback == "preferences" and reward_l1:
        typer.echo(f"note: --reward-l1 {reward_l1:g} is not used with --feedback preferences (comparisons leave "
                   f"the rewards' scale free: the prior would shrink it towards 0)", err=True)
    members = cfg.members if ensemble is None else ensemble
    run = _bad_input(fit, ds, arch, cfg, members, split_seed=split_seed, split_mode=split_mode,
                     out=out, data_source=source)
    _print_run(run, cfg)


def _print_run(run, cfg) -> None:
    """What `nmrm train` prints of a run: the single model's line, or one per member and the mean."""
    t = run.train
    if run.model.members == 1:
        c = run.chosen or 0  # keep_members best: the kept candidate's entry in the training record
        if run.chosen is not None:
            losses = ", ".join(f"{v:.4g}" for v in t.best_val_loss)
            typer.echo(f"best of {len(t.best_val_loss)} candidates on validation (losses {losses}): "
                       f"candidate {c}, seed {run.seeds[0]}")
        typer.echo(f"best epoch {t.best_epochs[c]}/{t.epochs_run} in {t.seconds:.1f} s; "
                   f"test {_metrics_line(run.test_metrics)}")
        if t.still_improving[c]:
            typer.echo(f"note: still improving at the epoch limit ({cfg.max_epochs}); more epochs may help")
    else:
        typer.echo(f"{run.model.members} members in one pass: {t.epochs_run} epochs in {t.seconds:.1f} s")
        for m, test in enumerate(run.member_test):
            flag = ", still improving at the limit" if t.still_improving[m] else ""
            typer.echo(f"  member {m} (seed {run.seeds[m]}, split {run.split_seeds[m]}): best epoch "
                       f"{t.best_epochs[m]}; test {_metrics_line(test)}{flag}")
        if run.test_metrics is not None:
            m = run.test_metrics
            typer.echo(f"ensemble mean: test {_metrics_line(m)}, mean return std {m['return_std']:.4f}")
        typer.echo(f"serving member (hidden state): {int(run.model.serving_member)}")
    typer.echo(f"checkpoint: {run.checkpoint} (+ .json)")


@app.command()
def evaluate(
    checkpoint: Path = typer.Option(..., help="checkpoint path (.pt or .json or the stem)"),
    data: Path = typer.Option(None, help="dataset .npz (default: regenerate the training data)"),
    bag: list[Path] = typer.Option(None, help="bag(s) of recorded episodes with OracleStep ground truth"),
    labeller: str = typer.Option(None, help="with --bag: whose labels to use if several labelled"),
    split: str = typer.Option("test", help="test | val | train | all (of the dataset)"),
) -> None:
    """Test-split return MSE and reward MSE of a checkpoint (the paper's table metrics)."""
    from .mil import CheckpointError, evaluate as evaluate_model, load_checkpoint
    from .mil.data import split_indices

    try:
        model, meta = load_checkpoint(checkpoint)
    except CheckpointError as exc:
        raise typer.BadParameter(str(exc)) from None
    if bag:
        ds, _ = _load_bags(bag, meta.task, labeller)
        if not ds.meta.get("oracle_ground_truth"):
            typer.echo("note: not every episode has OracleStep ground truth; reward MSE is against zeros there")
    elif data is None:
        source = meta.data.source
        if not source.regenerable:
            raise typer.BadParameter(f"checkpoint data source {str(source)!r} cannot be regenerated; give --data")
        if source.kind == "bags":
            ds, _ = _load_bags(source.paths, meta.task, None)
        elif source.kind == "file":
            ds, _ = _load_or_generate(Path(source.paths[0]), None, 0, 0)
        else:
            ds, _ = _load_or_generate(None, source.task, source.n, source.seed)
    else:
        ds, _ = _load_or_generate(data, None, 0, 0)
    if ds.state_size != model.config.input_size:
        raise typer.BadParameter(f"dataset states have size {ds.state_size}, the model takes "
                                 f"{model.config.input_size}")
    if split != "all":
        names = ("train", "val", "test")
        if split not in names:
            raise typer.BadParameter(f"--split must be one of {names + ('all',)}")
        ds = ds.subset(split_indices(len(ds), meta.split_seed or 0)[names.index(split)])
    m = evaluate_model(model, ds)
    what = f"{model.members}-member ensemble of " if model.members > 1 else ""
    typer.echo(f"{what}{model.config.architecture} on {ds.task} ({split}): {_metrics_line(m)} "
               f"(of the reward MSE, the mean error per step index: {m['reward_mse_time_profile']:.5f})")
    if meta.train_config.get("feedback") == "preferences":
        typer.echo("note: trained on preferences, which fix returns only up to an offset and a scale: "
                   "judge it by the preference accuracy and the reward correlation, not the MSEs")


@app.command()
def calibrate(
    checkpoint: Path = typer.Option(..., help="checkpoint path (.pt or .json or the stem), e.g. a model of comparisons"),
    out: Path = typer.Option(..., help="checkpoint path of the calibrated model (writes OUT.pt and OUT.json)",
                             callback=_output_file),
    data: Path = typer.Option(None, help="dataset .npz whose return-labelled episodes calibrate"),
    bag: list[Path] = typer.Option(None, help="bag(s) whose return labels calibrate (repeatable)"),
    labeller: str = typer.Option(None, help="with --bag: whose labels to use if several labelled"),
    labels: int = typer.Option(None, min=2, help="use this many return-labelled episodes (a seeded subset; "
                               "default all)"),
    seed: int = typer.Option(0, min=0, help="seed of the --labels subset"),
) -> None:
    """Give a model of comparisons the units of returns: fit each member's predicted returns to a few
    return labels (R' = gain R + bias L) and write a copy whose rewards are (r' - bias) / gain."""
    import numpy as np

    from .mil import CheckpointError, Run, evaluate as evaluate_model
    from .mil.calibration import CalibrationError, calibrate as calibrate_model, check_calibratable, fit_calibration
    from .mil.checkpoint import checkpoint_paths

    if (data is None) == (not bag):
        raise typer.BadParameter("give the return labels as --data FILE or --bag BAG (one of them)")
    if checkpoint_paths(out)[0].resolve() == checkpoint_paths(checkpoint)[0].resolve():
        raise typer.BadParameter(f"--out {out} is the checkpoint itself: give another path (nothing is overwritten)")
    try:
        run = Run.load(checkpoint)
    except CheckpointError as exc:
        raise typer.BadParameter(str(exc)) from None
    model = run.model
    _bad_input(check_calibratable, model)
    ds, source = _load_bags(bag, run.meta.task, labeller) if bag else _load_or_generate(data, None, 0, 0)
    if ds.state_size != model.config.input_size:
        raise typer.BadParameter(f"dataset states have size {ds.state_size}, the model takes {model.config.input_size}")
    labelled = np.flatnonzero(np.isfinite(ds.returns))
    if labels is not None:
        if labels > len(labelled):
            raise typer.BadParameter(f"--labels {labels}: the data has {len(labelled)} return-labelled episodes")
        labelled = np.sort(np.random.default_rng(seed).choice(labelled, labels, replace=False))
    ds = ds.subset(labelled)
    try:
        fit = fit_calibration(model, ds)
    except CalibrationError as exc:
        raise typer.BadParameter(str(exc)) from None
    calibrated = calibrate_model(model, fit)
    before, after = evaluate_model(model, ds), evaluate_model(calibrated, ds)
    m = int(model.serving_member)
    typer.echo(f"calibrated on {fit.labels} return labels ({source}): serving member's rewards were "
               f"{fit.gain[m]:.4g} r {fit.bias[m]:+.4g} per step; return MSE on them {before['return_mse']:.4f} -> "
               f"{after['return_mse']:.4f}")
    path = run.replace(model=calibrated, calibration={**fit.to_dict(), "from": str(checkpoint_paths(checkpoint)[0]),
                                                      "data": str(source)}).save(out)
    typer.echo(f"wrote {path}")


@app.command()
def explain(
    checkpoint: Path = typer.Option(..., help="checkpoint path (.pt or .json or the stem)"),
    out: Path = typer.Option(Path("runs/explain"), help="directory for the PNGs and index.html",
                             callback=_output_dir),
    bag: Path = typer.Option(None, help="a recording: embeddings of its episodes and per-episode views"),
    task: str = typer.Option(None, help="task (default: the checkpoint's)"),
    n: int = typer.Option(300, min=1, help="trajectories for the hidden-state embedding"),
    seed: int = typer.Option(1, min=0, help="data seed of the generated trajectories (without --bag)"),
    episodes: int = typer.Option(3, min=0, help="with --bag: how many per-episode views"),
) -> None:
    """Pictures of what a model learnt: hidden-state embeddings, reward maps, probe trajectories
    and (with --bag) recorded episodes, in OUT/index.html."""
    from .bags import BagError
    from .interpret import explain as write_views
    from .mil import CheckpointError

    try:
        figures = write_views(checkpoint, out, bag=bag, task=task, n=n, seed=seed, episodes=episodes)
    except (CheckpointError, BagError, ValueError) as exc:
        raise typer.BadParameter(str(exc)) from None
    typer.echo(f"{len(figures)} figures: {out / 'index.html'}")


@app.command()
def check(
    checkpoint: Path = typer.Option(..., help="checkpoint path (.pt or .json or the stem)"),
    agent_episodes: int = typer.Option(150, min=1, help="episodes of the short agent run of the reward-hacking check"),
    eval_episodes: int = typer.Option(50, min=1, help="greedy and random episodes compared"),
    seed: int = typer.Option(0, min=0, help="agent seed (and of the check's episodes)"),
    memory_only: bool = typer.Option(False, help="skip the agent run (the memory check only)"),
    oracle: str = typer.Option("", help=ORACLE_HELP + "; the checks compare the model with it"),
) -> None:
    """Is this model fit to train an agent on? The memory check (does the served state separate
    what the oracle's hidden state separates) and the reward-hacking check (a short agent's
    learnt vs oracle return). Run it before training an agent; exit code 1 if a check fails."""
    from .mil import CheckpointError, load_checkpoint
    from .rl.acceptance import hacking_check, memory_check
    from .tasks import check_task

    try:
        model, meta = load_checkpoint(checkpoint)
    except CheckpointError as exc:
        raise typer.BadParameter(str(exc)) from None
    from .oracles import make_oracle

    task = meta.task
    _bad_input(check_task, task)
    _bad_input(make_oracle, task, oracle)
    typer.echo(f"checking {checkpoint} ({model.config.architecture} on {task})")
    try:
        results = [memory_check(model, task, seed=12345 + seed, oracle=oracle)]
        typer.echo(results[-1].summary())
        if not memory_only:
            results.append(hacking_check(checkpoint, task, episodes=agent_episodes,
                                         eval_episodes=eval_episodes, seed=seed, oracle=oracle))
            typer.echo(results[-1].summary())
    except ValueError as exc:  # a user's oracle that misbehaves (OracleError), a checkpoint that does not fit
        raise typer.BadParameter(str(exc)) from None
    if not all(r.passed for r in results):
        from .rl.acceptance import next_step

        typer.echo(next_step(results, str(checkpoint), task, oracle))
        raise typer.Exit(1)


@app.command("discovery-server")
def discovery_server(
    server_id: int = typer.Option(0, "--id", min=0, max=255, help="server id (its position in ROS_DISCOVERY_SERVER)"),
    address: str = typer.Option("0.0.0.0", help="address to listen on"),
    port: int = typer.Option(11811, min=1025, max=65535, help="UDP port (Fast DDS: 1025-65535)"),
) -> None:
    """Run a Fast DDS Discovery Server (for networks without multicast); nodes then need
    ROS_DISCOVERY_SERVER=ADDRESS:PORT (docs/guide/several-machines.md). Ctrl-C stops it."""
    import os

    from .ros.discovery_server import server_command

    try:
        argv, env = server_command(server_id, address, port)
    except FileNotFoundError as exc:
        raise typer.BadParameter(str(exc)) from None
    os.execve(argv[0], argv, env)


rl_app = typer.Typer(help="Train and evaluate RL agents on learnt or oracle non-Markovian rewards.",
                     no_args_is_help=True)
app.add_typer(rl_app, name="rl")


@rl_app.command("train")
def rl_train(
    task: str = typer.Option(..., help=TASK_HELP),
    reward: str = typer.Option("model", help="model | oracle | oracle-no-hidden"),
    oracle: str = typer.Option("", help=ORACLE_HELP + "; it judges every episode"),
    checkpoint: Path = typer.Option(None, help="MIL checkpoint (reward model), trained on TASK"),
    episodes: int = typer.Option(None, min=1, help="training episodes (default: config/rl.yaml, 400 DQN / 800 SAC)"),
    seed: int = typer.Option(0, min=0, help="seed of the agent (weights, exploration) and of the episodes"),
    envs: int = typer.Option(1, min=1, help="environments stepped together (SB3 DummyVecEnv)"),
    out: Path = typer.Option(Path("runs/agent"), help="output directory: policy.zip, curve.csv, curve.png",
                             callback=_output_dir),
    config: Path = typer.Option(None, help="RL config YAML (default config/rl.yaml)", exists=True,
                                dir_okay=False, readable=True),
) -> None:
    """Train the paper's agent (double DQN, or SAC for Lunar Lander) on a non-Markovian reward;
    every episode is judged by the oracle (curve.csv)."""
    from .mil import CheckpointError
    from .rl import REWARD_KINDS, train_agent
    from .tasks import check_task

    _bad_input(check_task, task)
    if reward not in REWARD_KINDS:
        raise typer.BadParameter(f"unknown reward kind {reward!r}; use one of {', '.join(REWARD_KINDS)}")
    if reward == "model" and checkpoint is None:
        raise typer.BadParameter("--reward model needs --checkpoint (or use --reward oracle)")
    if episodes is not None and episodes < 1:
        raise typer.BadParameter(f"--episodes must be at least 1, got {episodes}")
    try:
        run = train_agent(task, reward, checkpoint=checkpoint, episodes=episodes, seed=seed, out=out,
                          n_envs=envs, config=config, oracle=oracle)
    except (CheckpointError, ValueError) as exc:
        raise typer.BadParameter(str(exc)) from None
    steps = sum(r.steps for r in run.curve.records)
    typer.echo(f"{len(run.curve.records)} episodes, {steps} steps in {run.seconds:.0f} s "
               f"({steps / max(run.seconds, 1e-9):.0f} steps/s); oracle return of the last 50 episodes "
               f"{run.curve.final_oracle_return():.3f}")
    typer.echo(f"wrote {out}/policy.zip, curve.csv, curve.png")
    typer.echo(run.collapse.summary())


@app.command("loop")
def loop_command(
    task: str = typer.Option(..., help=TASK_HELP),
    rounds: int = typer.Option(4, min=1, help="rounds of labelling, model training and RL (1: the offline baseline)"),
    labels_per_round: int = typer.Option(250, min=10, help="episodes labelled per round (round 0: screened "
                                                            "random episodes; then the agent's)"),
    episodes: int = typer.Option(None, min=1, help="the agent's training episodes over all rounds "
                                                  "(default: config/rl.yaml, 400 DQN / 800 SAC)"),
    seed: int = typer.Option(0, min=0, help="seed of the agent, its episodes, round 0's data and the models"),
    oracle: str = typer.Option("", help=ORACLE_HELP + "; it labels and judges every episode"),
    members: int = typer.Option(None, min=1, help="models per reward model (default: the task's training config)"),
    max_epochs: int = typer.Option(None, min=1, help="epoch limit of each training (default: the task's config)"),
    out: Path = typer.Option(Path("runs/loop"), help="output directory: labels.npz, model_<round>, agent/, loop.json",
                             callback=_output_dir),
    feedback: str = typer.Option("returns", help="what the oracle gives: returns (one per episode) | preferences "
                                                 "(a simulated teacher's comparisons, --labels-per-round of them "
                                                 "a round, each new episode against earlier ones) | both"),
    beta: float = BETA_OPT, mistake: float = MISTAKE_OPT, equal: float = EQUAL_OPT, gamma: float = GAMMA_OPT,
    skip: float = SKIP_OPT,
) -> None:
    """The reward-model <-> agent loop: each round labels episodes (the oracle's returns, or a
    simulated teacher's comparisons), retrains the MIL model on all labels so far (warm start) and
    lets the agent learn on it; the agent's replay buffer is relabelled with each new model."""
    from .datasets.preference_teacher import SimulatedTeacher
    from .mil import CheckpointError
    from .rl.reward_model_loop import check_loop_arguments, run_loop
    from .tasks import check_task

    _bad_input(check_task, task)
    _bad_input(check_loop_arguments, rounds, labels_per_round, episodes, feedback)
    _teach_check(feedback, None, beta, mistake, equal, gamma, skip)
    teacher = SimulatedTeacher(beta=beta, mistake=mistake, equal=equal, gamma=gamma, skip=skip)
    try:
        result = run_loop(task, rounds, labels_per_round, episodes=episodes, seed=seed, out=out, oracle=oracle,
                          members=members, max_epochs=max_epochs, log=typer.echo, feedback=feedback,
                          teacher=teacher)
    except (CheckpointError, ValueError) as exc:
        raise typer.BadParameter(str(exc)) from None
    typer.echo(result.summary())
    typer.echo(f"wrote {out}/loop.json, labels.npz, model_*.pt, agent/")


@rl_app.command("evaluate")
def rl_evaluate(
    policy: Path = typer.Option(..., help="policy.zip from `nmrm rl train` or the agent node"),
    task: str = typer.Option(..., help="the task the policy was trained on"),
    checkpoint: Path = typer.Option(None, help="the reward model it was trained with (default: agent.json)"),
    oracle: str = typer.Option(None, help="your own oracle that judges (default: agent.json's, else the task's)"),
    episodes: int = typer.Option(50, min=1, help="evaluation episodes"),
    seed: int = typer.Option(10**8, min=0, help="seed of the first evaluation episode"),
) -> None:
    """Mean oracle return (± SEM) of the greedy policy, and of a random policy on the same episodes."""
    from .mil import CheckpointError
    from .rl import evaluate_agent
    from .tasks import check_task

    _bad_input(check_task, task)
    try:
        result = evaluate_agent(policy, task, checkpoint=checkpoint, episodes=episodes, seed=seed,
                                oracle=oracle)
    except (CheckpointError, ValueError) as exc:
        raise typer.BadParameter(str(exc)) from None
    typer.echo(f"{task}, reward {result.reward}: {result.summary()}")


def _bad_input(fn, *args, **kwargs):
    """Call fn; turn a ValueError (unknown task, bad size...) into a clean CLI error."""
    try:
        return fn(*args, **kwargs)
    except ValueError as exc:
        raise typer.BadParameter(str(exc)) from None


def _metrics_line(m: dict) -> str:
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


def _dataset_summary(ds) -> str:
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


def _interrupt_on_stop_signals() -> dict:
    """SIGINT and SIGTERM raise KeyboardInterrupt, so an interrupted command cleans up (e.g. no
    half-written bag is left) and exits with 128 + the signal. SIGINT is handled even where it was
    inherited as ignored (a command started with `&` from a script): `kill -INT` must stop it."""
    stopped_by: dict = {}

    def interrupt(signum, frame):
        stopped_by["signal"] = int(signum)
        raise KeyboardInterrupt

    signal.signal(signal.SIGINT, interrupt)
    signal.signal(signal.SIGTERM, interrupt)
    return stopped_by


def main() -> None:
    """Console-script entry point. Errors (bad options, bad input files) are one line on stderr,
    `nmrm: error: ...`, exit code 2; `--help` and no arguments print the help."""
    from typer._click import exceptions as click_errors  # typer vendors click

    stopped_by = _interrupt_on_stop_signals()
    try:
        code = app(standalone_mode=False, prog_name="nmrm")
    except click_errors.NoArgsIsHelpError:  # the help was printed already
        raise SystemExit(0) from None
    except click_errors.ClickException as exc:
        where = f"{exc.ctx.command_path}: " if getattr(exc, "ctx", None) is not None else "nmrm: "
        typer.echo(f"{where}error: {' '.join(exc.format_message().split())}", err=True)
        raise SystemExit(exc.exit_code) from None
    except (typer.Abort, KeyboardInterrupt):
        stopped_by.setdefault("signal", int(signal.SIGINT))
    if "signal" in stopped_by:  # typer turns KeyboardInterrupt into exit code 130
        typer.echo(f"nmrm: interrupted ({signal.Signals(stopped_by['signal']).name})", err=True)
        raise SystemExit(128 + stopped_by["signal"])
    raise SystemExit(code if isinstance(code, int) else 0)


if __name__ == "__main__":
    main()
