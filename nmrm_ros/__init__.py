"""nmrm_ros: non-Markovian reward modelling with multiple-instance learning, as a ROS 2 graph.

The core (tasks, oracles, datasets, MIL models, training) is plain Python with no ROS import;
`nmrm_ros.ros` and `nmrm_ros.nodes` are the thin rclpy adapters around it.
"""

__version__ = "0.1.0"
