"""Topic names and QoS of the nmrm graph (the contract documented in README.md).

Names are relative ("nmrm/observation"), so a node's namespace or a remapping moves them.
All topics are reliable and volatile, keep-last with a deep queue: the graph runs in lock-step
(one observation in flight), and the labeller and recorder must not lose a step.
"""

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

OBSERVATION = "nmrm/observation"
ACTION = "nmrm/action"
REWARD_STEP = "nmrm/reward_step"
TRAJECTORY_RETURN = "nmrm/trajectory_return"
ORACLE_STEP = "nmrm/oracle_step"

ALL_TOPICS = (OBSERVATION, ACTION, REWARD_STEP, TRAJECTORY_RETURN, ORACLE_STEP)

STEP_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1000,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
