"""The documentation site builds with warnings as errors (mkdocs build --strict), and its generated
reference lists every node parameter, launch argument and CLI option the code has; a node parameter
or launch argument without a description stops the build."""

from __future__ import annotations

import html
import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from cli_tree import leaf_commands

ROOT = Path(__file__).resolve().parents[1]


def load_gen_pages():
    spec = importlib.util.spec_from_file_location("gen_pages", ROOT / "docs" / "gen_pages.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("site")
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}",
           "NO_MKDOCS_2_WARNING": "1", "DISABLE_MKDOCS_2_WARNING": "true"}
    res = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-d", str(out)], cwd=ROOT,
                         env=env, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-4000:]
    return out


def page_html(site: Path, page: str) -> str:
    return (site / page / "index.html").read_text()


def page_text(site: Path, page: str) -> str:
    return html.unescape(re.sub(r"<[^>]+>", "", page_html(site, page)))


def test_the_site_has_the_guide_reference_and_results(site):
    for page in ("getting-started", "guide/concepts", "guide/your-own-task", "guide/labelling",
                 "guide/several-machines", "reference/cli", "reference/nodes", "reference/topics",
                 "reference/launch", "reference/api/mil", "results", "results/findings", "changelog"):
        assert (site / page / "index.html").exists(), page
    assert "nmrm_ros.mil.train_model" in page_html(site, "reference/api/mil")
    assert "Recorded in commit" in page_text(site, "results/any_dataset")


def test_every_node_parameter_is_in_the_reference(site):
    gen = load_gen_pages()
    text = page_html(site, "reference/nodes")
    missing = [f"{node}.{name}" for node, module in gen.node_modules() for name in module.PARAMETERS
               if f"<code>{name}</code>" not in text]
    assert len(gen.node_modules()) >= 8
    assert not missing, missing


def test_every_launch_argument_is_in_the_reference(site):
    gen = load_gen_pages()
    text = page_html(site, "reference/launch")
    missing = [f"{path.name}: {name}" for path in (ROOT / "launch_scripts").glob("*.launch.yaml")
               for name, _, _ in gen.launch_args(path) if f"<code>{name}</code>" not in text]
    assert not missing, missing


def test_every_cli_option_is_in_the_reference(site):
    from nmrm_ros.cli import app

    text = page_text(site, "reference/cli")
    missing = []
    for path, command in leaf_commands(app):
        if f"nmrm {' '.join(path)}" not in text:
            missing.append(" ".join(path))
        missing += [f"{' '.join(path)} {opt}" for p in command.params for opt in p.opts
                    if opt.startswith("--") and opt not in text]
    assert not missing, missing


def test_a_node_parameter_without_a_description_stops_the_build(monkeypatch):
    from nmrm_ros.nodes import recorder_node
    from nmrm_ros.ros.node_main import Param

    gen = load_gen_pages()
    monkeypatch.setitem(recorder_node.PARAMETERS, "undocumented", Param(1, " "))
    with pytest.raises(gen.DocsError, match="recorder: parameter 'undocumented' has no description"):
        gen.nodes_page()


def test_a_launch_argument_without_a_description_stops_the_build(tmp_path):
    gen = load_gen_pages()
    path = tmp_path / "x.launch.yaml"
    path.write_text("launch:\n- arg: {name: task, default: key}\n")
    with pytest.raises(gen.DocsError, match="launch argument 'task' has no description"):
        gen.launch_args(path)


def test_the_head_results_were_trained_with_the_shipped_defaults():
    """bench/results/any_dataset/head is the table the docs call "at HEAD's defaults": every run's
    training config must be what config/mil_training.yaml gives its task today (fields added since
    are not compared). A default changed without its figures, or figures made with a --set that
    never reached the config, fail here."""
    import dataclasses
    import json

    from nmrm_ros.mil import load_train_config
    from nmrm_ros.mil.training import EXECUTION_SETTINGS

    runs = sorted((ROOT / "bench" / "results" / "any_dataset" / "head").glob("*_r*.json"))
    assert runs
    stale = []
    for path in runs:
        run = json.loads(path.read_text())
        shipped = dataclasses.asdict(load_train_config(run["task"], seed=run["config"]["seed"]))
        stale += [f"{path.name}: {k} {v!r} (shipped: {shipped[k]!r})"
                  for k, v in run["config"].items()
                  if k in shipped and shipped[k] != v and k not in EXECUTION_SETTINGS]
    assert not stale, "\n".join(stale)
