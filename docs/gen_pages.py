"""Pages generated from the code at build time (mkdocs-gen-files runs this; nothing is written to
the repository): every node's parameters from its `PARAMETERS`, the topics and messages from
`nmrm_ros.bags.schemas` and `msg_defs/msg/*.msg`, the launch files' arguments (with their descriptions), the Python API
(mkdocstrings), the benchmark results in `bench/results/` with the commit each was recorded in,
and the changelog.

A node parameter or launch argument without a description stops the build (`DocsError`): the
reference must say what every one is.
"""

from __future__ import annotations

import importlib
import pkgutil
import re
import subprocess
from pathlib import Path

import mkdocs_gen_files
import yaml

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results"
API_PACKAGES = ("tasks", "oracles", "datasets", "mil", "rl", "bags", "labelling", "interpret", "ros")


class DocsError(RuntimeError):
    """Something the reference must say is missing from the code."""


def cell(text) -> str:
    """Text for a Markdown table cell."""
    return str(text).replace("|", "\\|").replace("\n", " ")


def node_modules() -> list[tuple[str, object]]:
    """(node name, module) of every nmrm_ros/nodes/*_node.py, sorted by name."""
    import nmrm_ros.nodes as nodes

    found = []
    for info in pkgutil.iter_modules(nodes.__path__):
        if info.name.endswith("_node"):
            found.append((info.name[: -len("_node")], importlib.import_module(f"nmrm_ros.nodes.{info.name}")))
    return sorted(found, key=lambda x: x[0])


def nodes_page() -> str:
    out = ["# Nodes and their parameters", "",
           "Generated from each node file's `PARAMETERS` (`nmrm_ros/nodes/<name>_node.py`). Every node is",
           "its own process: `ros2 run nmrm_ros <name>` on a ROS 2 install, `.venv/lib/nmrm_ros/<name>`",
           "from the venv; `--help` prints the same table. Set parameters with `--ros-args -p name:=value`",
           "or a `ros__parameters` file (`config/graph.yaml`). A minimum is checked at start-up: a value",
           "below it stops the node with a one-line error.", ""]
    for name, module in node_modules():
        params = getattr(module, "PARAMETERS", None)
        if params is None:
            raise DocsError(f"nmrm_ros/nodes/{name}_node.py has no PARAMETERS")
        doc = (module.__doc__ or "").strip()
        first, _, rest = doc.partition("\n")
        out += [f"## `{name}`", "", first.split(":", 1)[-1].strip(), "",
                "| parameter | default | minimum | what |", "|---|---|---|---|"]
        for pname, p in params.items():
            if not p.description.strip():
                raise DocsError(f"node {name}: parameter {pname!r} has no description")
            minimum = "" if p.minimum is None else p.minimum
            out.append(f"| `{pname}` | `{cell(p.default)!s}` | {minimum} | {cell(p.description)} |")
        out += ["", f"How `{name}` works (`nmrm_ros/nodes/{name}_node.py`):", "", "```text", rest.strip(), "```", ""]
    return "\n".join(out)


def topics_page() -> str:
    from nmrm_ros.bags.schemas import STANDARD_TYPES, TOPIC_TYPES
    from nmrm_ros.ros import topics

    out = ["# Topics and messages", "",
           "Generated from `nmrm_ros.bags.schemas.TOPIC_TYPES` and `msg_defs/msg/*.msg`.", "",
           (topics.__doc__ or "").strip(), "",
           "| topic | type | what |", "|---|---|---|"]
    msg_dir = ROOT / "msg_defs" / "msg"
    for topic, type_name in TOPIC_TYPES.items():
        pkg, _, short = type_name.split("/")
        if pkg == "nmrm_msgs":
            text = (msg_dir / f"{short}.msg").read_text()
            lead = " ".join(l.lstrip("# ").strip() for l in text.splitlines() if l.startswith("#"))
            what, anchor = lead, f"[`{type_name}`](#{short.lower()})"
        else:
            what, anchor = "standard message (recorded by default)", f"`{type_name}`"
        out.append(f"| `{topic}` | {anchor} | {cell(what)} |")
    out.append("")
    for msg in sorted(msg_dir.glob("*.msg")):
        out += [f"## {msg.stem}", "", f"`nmrm_msgs/msg/{msg.stem}` (`msg_defs/msg/{msg.name}`):", "",
                "```text", msg.read_text().rstrip(), "```", ""]
    for type_name, text in STANDARD_TYPES.items():
        out += [f"## {type_name.split('/')[-1]}", "", f"`{type_name}` (the standard message):", "",
                "```text", text.rstrip(), "```", ""]
    return "\n".join(out)


def launch_args(path: Path) -> list[tuple[str, str, str]]:
    """(name, default, description) of a launch file's arguments (`ros2 launch FILE --show-args`
    prints the same descriptions)."""
    doc = yaml.safe_load(path.read_text())
    found = []
    for entry in doc["launch"]:
        if "arg" in entry:
            arg = entry["arg"]
            if not str(arg.get("description", "")).strip():
                raise DocsError(f"{path.name}: launch argument {arg['name']!r} has no description")
            found.append((arg["name"], str(arg.get("default", "")), arg["description"]))
    return found


def launch_page() -> str:
    out = ["# Launch files", "",
           "Generated from `launch_scripts/*.launch.yaml`. Run one with `nmrm launch FILE name:=value ...`",
           "or `ros2 launch FILE name:=value ...`; `ros2 launch FILE --show-args` lists the arguments too.", ""]
    for path in sorted((ROOT / "launch_scripts").glob("*.launch.yaml")):
        head = []
        for line in path.read_text().splitlines():
            if not line.startswith("#"):
                break
            head.append(line.lstrip("#")[1:] if line.startswith("# ") else line.lstrip("#"))
        out += [f"## `{path.name}`", "", "```text", "\n".join(head).strip(), "```", "",
                "| argument | default | what |", "|---|---|---|"]
        out += [f"| `{n}` | `{cell(d)}` | {cell(w)} |" for n, d, w in launch_args(path)]
        out.append("")
    return "\n".join(out)


def api_pages() -> list[tuple[str, str]]:
    pages = []
    for pkg in API_PACKAGES:
        module = importlib.import_module(f"nmrm_ros.{pkg}")
        first = ((module.__doc__ or "").strip().splitlines() or [""])[0]
        pages.append((f"reference/api/{pkg}.md",
                      f"# `nmrm_ros.{pkg}`\n\n{first}\n\n::: nmrm_ros.{pkg}\n    options:\n"
                      f"      show_submodules: true\n"))
    return pages


def git_commit(path: Path) -> str:
    """'<short hash> (<date>)' of the last commit that changed `path`, or 'not committed'."""
    res = subprocess.run(["git", "log", "-1", "--format=%h (%cs)", "--", str(path)], cwd=ROOT,
                         capture_output=True, text=True)
    return res.stdout.strip() or "not committed"


def results_pages() -> list[tuple[str, str]]:
    """One page per top-level entry of bench/results (its files, then each subdirectory's): every
    .txt in full, every .png shown (copied into the site), .json/.csv/.log listed by name."""
    groups: dict[str, list[Path]] = {}
    for f in sorted(RESULTS.rglob("*")):
        if f.is_file():
            rel = f.relative_to(RESULTS)
            groups.setdefault(rel.parts[0] if len(rel.parts) > 1 else "", []).append(f)
    pages = []
    for group, files in sorted(groups.items()):
        title = "bench/results" if not group else f"bench/results/{group}"
        out = [f"# `{title}`", "",
               "Generated from the files as committed, each with the commit that last changed it. The",
               "command that produced a table is in its first lines or in [Findings](findings.md).", ""]
        by_dir: dict[Path, list[Path]] = {}
        for f in files:
            by_dir.setdefault(f.parent.relative_to(RESULTS), []).append(f)
        for rel, dir_files in by_dir.items():
            level = "##"
            if len(rel.parts) > 1:
                out += [f"## `{rel}/`", ""]
                level = "###"
            others = []
            for f in dir_files:
                name = f.relative_to(RESULTS)
                if f.suffix == ".txt":
                    out += [f"{level} `{f.name}`", "", f"Recorded in commit {git_commit(f)}.", "", "```text",
                            f.read_text(errors="replace").rstrip(), "```", ""]
                elif f.suffix == ".png":
                    with mkdocs_gen_files.open(f"results/files/{name}", "wb") as dst:
                        dst.write(f.read_bytes())
                    out += [f"{level} `{f.name}`", "", f"Recorded in commit {git_commit(f)}.", "",
                            f"![{f.name}](files/{name})", ""]
                else:
                    others.append(f"`{f.name}`")
            if others:
                out += [f"Data files in `bench/results/{rel}/`: " + ", ".join(others) + ".", ""]
        page = "results/summary.md" if not group else f"results/{group}.md"
        pages.append((page, "\n".join(out)))
    index = ["# Results", "",
             "Every benchmark's latest output, as committed in `bench/results/`: generated, one page per",
             "directory. What the numbers mean, and the commands that made them: [Findings](findings.md).", ""]
    index += [f"- [`{p[len('results/'):-3]}`]({p[len('results/'):]})" for p, _ in pages]
    pages.append(("results/index.md", "\n".join(index) + "\n"))
    return pages


def write(path: str, text: str) -> None:
    with mkdocs_gen_files.open(path, "w") as f:
        f.write(text)


def generate() -> None:
    """Write every generated page into the build."""
    write("reference/nodes.md", nodes_page())
    write("reference/topics.md", topics_page())
    write("reference/launch.md", launch_page())
    for p, t in api_pages():
        write(p, t)
    for p, t in results_pages():
        write(p, t)
    write("changelog.md", (ROOT / "CHANGELOG.md").read_text())


if __name__ == "<run_path>":  # run by mkdocs-gen-files during a build
    generate()
