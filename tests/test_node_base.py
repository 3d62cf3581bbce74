"""Every node executable is an `NmrmNode`: one protocol (parameters, exit code, diagnostics,
leaving with its upstream, close, main), no node of its own making."""

import importlib
import re
from pathlib import Path

import pytest

from nmrm_ros.ros.node_base import NmrmNode

SETUP = (Path(__file__).resolve().parents[1] / "setup.py").read_text()
EXECUTABLES = dict(re.findall(r'"(\w+)": "(nmrm_ros\.nodes\.\w+):main"', SETUP))


def test_every_node_module_is_an_executable():
    modules = {p.stem for p in (Path(__file__).resolve().parents[1] / "nmrm_ros" / "nodes").glob("*_node.py")}
    assert {m.rsplit(".", 1)[1] for m in EXECUTABLES.values()} == modules


@pytest.mark.parametrize("executable", sorted(EXECUTABLES))
def test_node_class_follows_the_protocol(executable):
    module = importlib.import_module(EXECUTABLES[executable])
    nodes = [v for v in vars(module).values()
             if isinstance(v, type) and issubclass(v, NmrmNode) and v is not NmrmNode and v.__module__ == module.__name__]
    assert len(nodes) == 1, f"{module.__name__}: one NmrmNode per file"
    node = nodes[0]
    assert node.executable == executable
    assert node.PARAMETERS is module.PARAMETERS
    # the parameter that the base class's exit_with_upstream reads is declared wherever it is used
    source = Path(module.__file__).read_text()
    if "self.exit_with_upstream(" in source:
        assert "exit_with_upstream" in node.PARAMETERS
    assert "run_node(" not in source and "getattr(node" not in source
