"""Every parameter of every node refuses a value of the wrong kind or below its minimum with a
one-line error naming it (property-based, with Hypothesis): declared on a real rclpy node with the
value as an override, exactly as `--ros-args -p name:=value` gives it. (The nodes turn that
NodeError into `[node] error: ...` and exit code 2: tests/test_faults.py runs the processes.)"""

from __future__ import annotations

import importlib
import itertools
import pkgutil

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

rclpy = pytest.importorskip("rclpy")

from rclpy.parameter import Parameter  # noqa: E402

import nmrm_ros.nodes as nodes  # noqa: E402
from nmrm_ros.ros.node_main import NodeError, declare_parameters  # noqa: E402

TABLES = {info.name[: -len("_node")]: importlib.import_module(f"nmrm_ros.nodes.{info.name}").PARAMETERS
          for info in pkgutil.iter_modules(nodes.__path__) if info.name.endswith("_node")}
CASES = sorted((node, name) for node, table in TABLES.items() for name in table)

TEXT = st.text(st.characters(codec="ascii", exclude_categories=("Cc",)), min_size=1, max_size=12)
INT64 = st.integers(-2**63, 2**63 - 1)  # what a ROS integer parameter can hold
NON_INTEGRAL = st.floats(allow_nan=False, allow_infinity=False).filter(lambda x: x != int(x))


def wrong_values(default, minimum):
    """Strategies of override values that the parameter must refuse."""
    if isinstance(default, bool):
        return [INT64, NON_INTEGRAL, TEXT]
    if isinstance(default, int):
        found = [NON_INTEGRAL, TEXT, st.booleans()]
        if minimum is not None:
            found.append(st.integers(1, 10**12).map(lambda d: int(minimum) - d))
        return found
    if isinstance(default, float):  # an integer is converted (lossless): not wrong
        found = [TEXT, st.booleans()]
        if minimum is not None:
            found.append(st.floats(1e-6, 1e12).map(lambda d: float(minimum) - d))
        return found
    if isinstance(default, str):
        return [INT64, NON_INTEGRAL, st.booleans()]
    if isinstance(default, (list, tuple)):  # string arrays: one string is converted (lossless)
        return [INT64, st.booleans(), NON_INTEGRAL]
    raise AssertionError(f"a parameter type this test does not know: {default!r}")


@st.composite
def wrong_override(draw):
    node, name = draw(st.sampled_from(CASES))
    p = TABLES[node][name]
    return node, name, draw(st.one_of(*wrong_values(p.default, p.minimum)))


@pytest.fixture(scope="module")
def context():
    ctx = rclpy.context.Context()
    rclpy.init(args=[], context=ctx)
    yield ctx
    rclpy.shutdown(context=ctx)


counter = itertools.count()


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                  HealthCheck.function_scoped_fixture])
@given(wrong_override())
def test_a_wrong_parameter_value_is_refused_in_one_line(context, case):
    node_name, name, value = case
    node = rclpy.node.Node(f"probe_{next(counter)}", context=context,
                           parameter_overrides=[Parameter(name, value=value)])
    try:
        with pytest.raises(NodeError) as err:
            declare_parameters(node, TABLES[node_name])
    finally:
        node.destroy_node()
    message = str(err.value)
    assert f"parameter {name!r}" in message and "\n" not in message, (node_name, name, value, message)


def test_every_parameter_is_of_a_kind_this_test_covers():
    assert len(TABLES) >= 8 and len(CASES) > 60
    for node, name in CASES:
        wrong_values(TABLES[node][name].default, TABLES[node][name].minimum)
