"""Every nmrm_msgs message imports and round-trips through rclpy.serialization, field for field."""

import math

import pytest
from rclpy.serialization import deserialize_message, serialize_message

from nmrm_msgs.msg import AgentAction, EnvObservation, OracleStep, RewardStep, TrajectoryReturn

SAMPLES = [
    EnvObservation(task="charger", episode=2**40 + 3, step=99, state=[0.25, 0.75],
                   terminated=False, truncated=True),
    AgentAction(episode=5, step=17, action=[3.0]),
    RewardStep(episode=5, step=17, state=[0.5, 0.5], hidden=[0.1, -0.2],
               augmented_state=[0.5, 0.5, 0.1, -0.2], reward=-1.5, source="csc_lstm/key"),
    TrajectoryReturn(task="timer", episode=11, length=100, return_value=-12.345678901234,
                     labeller="oracle/timer"),
    OracleStep(episode=11, step=50, hidden=[51.0], reward=1.0),
]


@pytest.mark.parametrize("msg", SAMPLES, ids=lambda m: type(m).__name__)
def test_round_trip(msg):
    msg.header.frame_id = "nmrm"
    msg.header.stamp.sec = 1234
    msg.header.stamp.nanosec = 5678
    data = serialize_message(msg)
    assert isinstance(data, bytes) and len(data) > 0
    back = deserialize_message(data, type(msg))
    assert back == msg  # rosidl messages compare field by field


def test_float64_return_keeps_precision():
    msg = TrajectoryReturn(return_value=math.pi * 1e6)
    back = deserialize_message(serialize_message(msg), TrajectoryReturn)
    assert back.return_value == math.pi * 1e6


def test_contract_fields_present():
    """The fields the graph relies on (issue #2's contract) exist with the right types."""
    expected = {
        EnvObservation: {"header": "std_msgs/Header", "task": "string", "episode": "uint64",
                         "step": "uint32", "state": "sequence<float>", "terminated": "boolean",
                         "truncated": "boolean"},
        AgentAction: {"header": "std_msgs/Header", "episode": "uint64", "step": "uint32",
                      "action": "sequence<float>"},
        RewardStep: {"header": "std_msgs/Header", "episode": "uint64", "step": "uint32",
                     "state": "sequence<float>", "hidden": "sequence<float>",
                     "augmented_state": "sequence<float>", "reward": "float", "source": "string"},
        TrajectoryReturn: {"header": "std_msgs/Header", "task": "string", "episode": "uint64",
                           "length": "uint32", "return_value": "double", "labeller": "string"},
        OracleStep: {"header": "std_msgs/Header", "episode": "uint64", "step": "uint32",
                     "hidden": "sequence<float>", "reward": "float"},
    }
    for cls, fields in expected.items():
        types = cls.get_fields_and_field_types()
        for name, typ in fields.items():
            assert types.get(name) == typ, (cls.__name__, name, types.get(name))

