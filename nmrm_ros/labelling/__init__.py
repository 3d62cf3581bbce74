"""Labelling by people: the queue of finished episodes, the labels bag, and the web page's app
(served by `nmrm_ros.web_server`).

Plain Python (aiohttp for the page); the `labeller_web` node is the ROS adapter around them.
"""

from .frames import FrameStore
from .label_store import LabelStore, StoredLabel
from .queue import Episode, LabelError, LabelQueue, return_range
from .waiting_episodes import WaitingEpisode, WaitingEpisodes
from .web_app import make_app

__all__ = ["Episode", "FrameStore", "LabelError", "LabelQueue", "LabelStore", "StoredLabel", "WaitingEpisode",
           "WaitingEpisodes", "make_app", "return_range"]
