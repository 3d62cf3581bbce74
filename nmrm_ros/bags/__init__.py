"""MCAP bags (rosbag2-compatible): writing, reading, repair, and episodes <-> datasets.

Plain Python (mcap, mcap-ros2-support); no rclpy import. The recorder and replay nodes are thin
adapters around these modules.
"""

from .episodes import BagDatasetReport, load_bag_dataset, write_dataset_bag
from .reader import BagError, bag_files, bag_summary, iter_decoded, iter_raw
from .repair import RepairReport, repair_bag
from .writer import BagWriter

__all__ = ["BagDatasetReport", "BagError", "BagWriter", "RepairReport", "bag_files", "bag_summary",
           "iter_decoded", "iter_raw", "load_bag_dataset", "repair_bag", "write_dataset_bag"]
