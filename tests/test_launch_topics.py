"""``palpa launch --check`` lists each node's topics, read from the class source (no node is started)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from messages import Text
from nodes.demo import Listener, Talker
from nodes.probe.fibre_reader import FibreReader
from palpa import Node
from palpa.launch.topics import declared_topics
from palpa.timing.simclock import ClockSource
from tests.test_launch_smoke import REPO


def test_declared_topics_with_namespace_and_remap() -> None:
    assert declared_topics(Talker) == {"publishes": ["chatter"], "subscribes": []}
    assert declared_topics(Listener, "left", {"chatter": "/talk"}) == {
        "publishes": ["left/chatter_len"], "subscribes": ["talk"]}
    fibre = declared_topics(FibreReader)
    assert fibre["publishes"] == ["probe/heights", "probe/status", "sim/truth/fibre"]  # the last: the sim device
    assert fibre["subscribes"] == ["pressure/state", "robot/pose"]  # the sim driver's inputs
    assert declared_topics(ClockSource) == {"publishes": [], "subscribes": []}  # runtime topics are not listed


def user_topic(name: str) -> str:
    return f"out/{name}"


class ComputedTopics(Node):
    """A node whose topics are computed: a user's by a function, one from a parameter."""

    def setup(self) -> None:
        self.publisher(user_topic(self.name), Text)
        self.publisher(self.name + "/x", Text)


def test_a_computed_topic_is_said_to_be_computed() -> None:
    assert declared_topics(ComputedTopics) == {"publishes": ["(computed)"], "subscribes": []}


@pytest.mark.system
def test_check_prints_topics() -> None:
    out = subprocess.run([sys.executable, "-m", "palpa.cli.main", "launch", "--check",
                          str(REPO / "launch" / "talker_listener.yaml")], capture_output=True, text=True,
                         timeout=60, cwd=REPO)
    assert out.returncode == 0, out.stderr
    assert "publishes: [chatter_len]" in out.stdout and "subscribes: [chatter]" in out.stdout
