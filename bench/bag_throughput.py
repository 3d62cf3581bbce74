"""Benchmark: bag throughput.

    .venv/bin/python bench/bag_throughput.py [--messages 50000]

- recording: a publisher process sends --messages EnvObservation messages as fast as it can to the
  recorder node (separate processes, reliable keep-all topics); prints what the recorder wrote per
  second by its own count over its own clock (first to last write, from its closing log line),
  the publisher's loop rate beside it, and whether any message was dropped (the bag is read back
  and counted);
- writing in-process (`nmrm dataset generate` path: dict -> CDR -> MCAP), messages/s;
- reading: raw CDR (mcap), decoded (mcap_ros2), rosbags' AnyReader, and building the MIL dataset
  (`load_bag_dataset`), messages/s.
Run with scripts/ros_env.sh sourced.
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from ament_index_python.packages import get_package_prefix

PUBLISHER = r'''
import sys, time, rclpy
from nmrm_msgs.msg import EnvObservation
from nmrm_ros.ros.topics import OBSERVATION, STEP_QOS
n = int(sys.argv[1])
rclpy.init()
node = rclpy.create_node("bench_publisher")
pub = node.create_publisher(EnvObservation, OBSERVATION, STEP_QOS)
while pub.get_subscription_count() < 1:
    rclpy.spin_once(node, timeout_sec=0.05)
time.sleep(0.5)
t0 = time.perf_counter()
for i in range(n):
    pub.publish(EnvObservation(task="key", episode=i // 101, step=i % 101, state=[0.5, 0.5],
                               truncated=i % 101 == 100))
print(time.perf_counter() - t0, flush=True)
from rclpy.duration import Duration
pub.wait_for_all_acked(Duration(seconds=60))
node.destroy_node(); rclpy.shutdown()
'''


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--messages", type=int, default=50000)
    args = parser.parse_args()
    from nmrm_ros.bags import bag_summary, iter_decoded, iter_raw, load_bag_dataset, write_dataset_bag
    from nmrm_ros.datasets import generate_screened

    tmp = Path(tempfile.mkdtemp())
    rec_exe = Path(get_package_prefix("nmrm_ros")) / "lib" / "nmrm_ros" / "recorder"
    out = tmp / "recorded"
    rec = subprocess.Popen([str(rec_exe), "--ros-args", "-p", f"output:={out}", "-p",
                            "topics:=['/nmrm/observation']"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    pub = subprocess.run([sys.executable, "-c", PUBLISHER, str(args.messages)], capture_output=True, text=True,
                         timeout=600)
    if pub.returncode != 0:
        raise SystemExit(f"publisher failed:\n{pub.stderr}")
    publish_s = float(pub.stdout.strip().splitlines()[-1])
    time.sleep(1.0)
    rec.send_signal(signal.SIGINT)
    log, _ = rec.communicate(timeout=60)
    match = re.search(r"(\d+) messages written in ([\d.]+) s \((\d+) msg/s\)", log)
    if match is None:
        raise SystemExit(f"no write rate in the recorder's log:\n{log}")
    written, span, rate = int(match[1]), float(match[2]), int(match[3])
    recorded = bag_summary(out)["/nmrm/observation"][1]
    print(f"# bag throughput, {args.messages} messages")
    print(f"recording (publisher -> recorder, separate processes): the recorder wrote {written} messages "
          f"in {span:.2f} s = {rate} msg/s (its own count and clock); recorded in the bag "
          f"{recorded}/{args.messages} ({'no drop' if recorded == args.messages else f'{args.messages - recorded} DROPPED'}); "
          f"the publisher's loop ran at {args.messages / publish_s:.0f} msg/s")

    episodes = max(1, args.messages // 303)
    ds = generate_screened("key", episodes, seed=0)
    t0 = time.perf_counter()
    path = write_dataset_bag(ds, tmp / "generated")
    seconds = time.perf_counter() - t0
    total = sum(n for _, n in bag_summary(path).values())
    print(f"writing in-process (dict -> CDR -> MCAP): {total} messages in {seconds:.2f} s = {total / seconds:.0f} msg/s")
    for name, fn in (("raw CDR (mcap)", lambda: sum(1 for _ in iter_raw(path))),
                     ("decoded (mcap_ros2)", lambda: sum(1 for _ in iter_decoded(path))),
                     ("rosbags AnyReader", lambda: _rosbags(path))):
        t0 = time.perf_counter()
        n = fn()
        s = time.perf_counter() - t0
        print(f"reading {name}: {n} messages in {s:.2f} s = {n / s:.0f} msg/s")
    t0 = time.perf_counter()
    _, report = load_bag_dataset([path])
    s = time.perf_counter() - t0
    print(f"building the MIL dataset (load_bag_dataset): {report.episodes_used} episodes, {total} messages "
          f"in {s:.2f} s = {total / s:.0f} msg/s")


def _rosbags(path) -> int:
    from rosbags.highlevel import AnyReader

    n = 0
    with AnyReader([Path(path)]) as reader:
        for conn, _, raw in reader.messages():
            reader.deserialize(raw, conn.msgtype)
            n += 1
    return n


if __name__ == "__main__":
    main()
