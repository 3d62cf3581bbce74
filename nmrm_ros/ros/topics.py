"""Topic names and QoS of the nmrm graph (the contract: docs/guide/graph.md).

Names are relative ("nmrm/observation"), so a node's namespace or a remapping moves them.
All topics are reliable, volatile and keep-all: no message is ever dropped for lack of queue
space. In lock-step only one observation is in flight; a replay publishes as fast as it can and
the subscribers' queues absorb the difference (memory grows instead of messages being lost).
"""

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

OBSERVATION = "nmrm/observation"
ACTION = "nmrm/action"
REWARD_STEP = "nmrm/reward_step"
TRAJECTORY_RETURN = "nmrm/trajectory_return"
ORACLE_STEP = "nmrm/oracle_step"
TRAJECTORY_PREFERENCE = "nmrm/trajectory_preference"  # labellers' pairwise comparisons of episodes
FRAME = "nmrm/frame"  # sensor_msgs/CompressedImage: env_sim's rendered frames (render:=true)
#: sensor_msgs/CompressedImage (PNG): the pixels of an image task's state, beside its
#: EnvObservation (which then carries the vector part only): `nmrm_ros.tasks.image_states`
OBSERVATION_IMAGE = "nmrm/observation_image"

ALL_TOPICS = (OBSERVATION, ACTION, REWARD_STEP, TRAJECTORY_RETURN, ORACLE_STEP, TRAJECTORY_PREFERENCE, FRAME,
              OBSERVATION_IMAGE)


def observation_image_topic(topic: str) -> str:
    """The observation-image topic beside a step topic of the same graph:
    'robot1/nmrm/reward_step' -> 'robot1/nmrm/observation_image'."""
    prefix = topic.rpartition("/")[0]
    return f"{prefix}/observation_image" if prefix else "observation_image"

STEP_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_ALL,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
