"""The labelling page's load time and a label's round trip (click -> topic -> bag), in a real browser.

A labeller_web node (a real process) holds `--episodes` finished Key episodes (env_sim + a random
agent). Headless Chromium (Debian's, driven by Playwright) then, `--repeats` times: loads the page
and waits until the first episode's path is drawn (page load = `goto` until the SVG polyline
exists); types a return and clicks "Label"; the round trip is from the click until this process's
rclpy subscription receives the TrajectoryReturn. The node writes and flushes the label to its
labels bag before it publishes, so the topic's arrival bounds the bag write too; at the end the
bag is read back and must hold every label.

    .venv/bin/python bench/labelling_page_latency.py --repeats 20
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
from nmrm_ros.ros.ament_paths import node_command


def start(name: str, **params) -> subprocess.Popen:
    return subprocess.Popen(node_command(name, **params), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--chromium", default=shutil.which("chromium") or shutil.which("chromium-browser"))
    args = parser.parse_args()
    if not args.chromium:
        print("needs Debian's chromium (apt install chromium)", file=sys.stderr)
        return 2
    os.environ.setdefault("ROS_DOMAIN_ID", "77")
    import rclpy
    from playwright.sync_api import sync_playwright

    from nmrm_msgs.msg import TrajectoryReturn
    from nmrm_ros.bags import iter_decoded
    from nmrm_ros.ros.discovery import use_discovery_profile
    from nmrm_ros.ros.node_main import _executor
    from nmrm_ros.ros.topics import STEP_QOS, TRAJECTORY_RETURN

    use_discovery_profile()
    work = Path(tempfile.mkdtemp(prefix="page_latency_"))
    web = start("labeller_web", task="key", port=0, person="bench", labels_dir=work / "labels")
    url = None
    for line in web.stdout:
        if "labelling page: " in line:
            url = line.split("labelling page: ")[1].split()[0]
            break
    threading.Thread(target=lambda: [None for _ in web.stdout], daemon=True).start()
    agent = start("agent", observe="observation", exit_with_upstream=True)
    sim = start("env_sim", task="key", episodes=args.repeats, wait_for_nodes="[labeller_web]")
    for proc in (sim, agent):
        proc.communicate(timeout=120)

    rclpy.init()
    node = rclpy.create_node("latency_bench")
    arrived: dict = {}
    node.create_subscription(TrajectoryReturn, TRAJECTORY_RETURN,
                             lambda m: arrived.setdefault(m.episode, time.perf_counter()), STEP_QOS)
    executor = _executor()
    executor.add_node(node)
    spinning = True

    def spin() -> None:
        while spinning:
            executor.spin_once(timeout_sec=0.01)

    spinner = threading.Thread(target=spin, daemon=True)
    spinner.start()
    time.sleep(3.0)  # the subscription matches the node's publisher
    loads, trips = [], []
    try:
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=args.chromium, args=["--no-sandbox"])
            page = browser.new_page()
            for i in range(args.repeats):
                t0 = time.perf_counter()
                page.goto(url)
                page.wait_for_selector("#arena polyline")
                loads.append(time.perf_counter() - t0)
                episode = int(page.text_content("#title").split()[1])
                page.fill("#return", "5")
                t_click = time.perf_counter()
                page.click("#submit")
                deadline = time.monotonic() + 10
                while episode not in arrived and time.monotonic() < deadline:
                    time.sleep(0.0005)
                trips.append(arrived[episode] - t_click)
            browser.close()
    finally:
        spinning = False
        spinner.join(2)
        web.terminate()
        web.wait(30)
        node.destroy_node()
        rclpy.shutdown()
    session = next(p for p in (work / "labels").iterdir() if p.is_dir())
    stored = [m.episode for _, _, _, m in iter_decoded(session)]
    assert len(stored) == args.repeats, stored
    ms = lambda a: np.asarray(a) * 1e3  # noqa: E731
    print(f"page load (goto until the first path is drawn), {args.repeats} loads: median "
          f"{np.median(ms(loads)):.0f} ms, p90 {np.percentile(ms(loads), 90):.0f} ms, max {ms(loads).max():.0f} ms")
    print(f"label round trip (click -> TrajectoryReturn received; flushed to the bag before), "
          f"{args.repeats} labels: median {np.median(ms(trips)):.1f} ms, p90 {np.percentile(ms(trips), 90):.1f} ms, "
          f"max {ms(trips).max():.1f} ms; all {len(stored)} in the labels bag")
    shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
