"""Topic names: validity as ROS 2 defines it, resolution in a namespace, --ros-args split."""

from __future__ import annotations

import pytest
from sysid_node.topics import resolve, split_ros_args, topic_name_error

from sysid_node import params as P


@pytest.mark.parametrize(
    "name", ["vibration", "/vibration", "left_wing/vibration", "~/x", "~", "_a1/b_2", "{node}/x"]
)
def test_valid_names(name):
    assert topic_name_error(name) == ""


@pytest.mark.parametrize(
    ("name", "fragment"),
    [("", "empty"), ("/", "no name"), ("a//b", "empty name token"), ("a/", "empty name token"),
     ("1a", "must start"), ("a-b", "letters, digits"), ("~x", "'~' must be followed"),
     ("a b", "letters, digits")],
)
def test_invalid_names_have_a_reason(name, fragment):
    assert fragment in topic_name_error(name)


def test_resolution_follows_the_namespace():
    assert resolve("vibration") == "/vibration"
    assert resolve("vibration", "/left_wing") == "/left_wing/vibration"
    assert resolve("vibration", "left_wing/") == "/left_wing/vibration"
    assert resolve("/vibration", "/left_wing") == "/vibration"
    with pytest.raises(ValueError, match="private"):
        resolve("~/x", "/ns")


def test_default_topics_are_relative_so_a_namespace_moves_them():
    from notch_filter_node import params as N

    names = [P.SPECS["output_topic"].default, P.SPECS["input_topic"].default]
    names += [s.default for s in N.PARAMS if s.name.endswith("_topic")]
    assert names and all(n and not n.startswith("/") for n in names)
    assert P.validate_set(P.defaults()) == "" and N.validate_set(N.defaults()) == ""


def test_ros_args_are_split_from_the_tools_own():
    own, ros = split_ros_args(["a", "--ros-args", "-r", "__ns:=/l", "--", "--rate", "2"])
    assert own == ["a", "--rate", "2"]
    assert ros == ["--ros-args", "-r", "__ns:=/l"]
    assert split_ros_args(["x"]) == (["x"], [])
