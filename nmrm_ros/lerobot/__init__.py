"""LeRobot datasets (format v3.0) in and out: episodes, camera frames, labels, comparisons and
learnt rewards, without LeRobot itself (it pins an older torch than ours) and without the hub.

    export_lerobot(["bags/key_2000"], "out/key_lerobot", checkpoint="runs/key.pt")   # bag -> LeRobot
    import_lerobot("out/key_lerobot", "bags/key_again")                              # LeRobot -> bag

`format` is the on-disk layout LeRobot 0.4.x reads (data and episode parquets, meta/info.json,
meta/stats.json, meta/tasks.parquet, MP4 videos); `video` encodes and decodes the camera streams
(PyAV); `to_lerobot` and `from_lerobot` are the two directions. What LeRobot has no place for
(the final observation of an episode, the labels with who gave them, the comparisons) is kept in
`meta/nmrm/`, which LeRobot ignores; docs/guide/lerobot.md says what maps to what.
"""

from .format import LeRobotError
from .from_lerobot import import_lerobot
from .to_lerobot import export_lerobot

__all__ = ["LeRobotError", "export_lerobot", "import_lerobot"]
