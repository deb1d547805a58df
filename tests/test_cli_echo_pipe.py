"""``palpa topic echo X | head``: when the reader of stdout goes away the tool ends quietly, status 0, and sends no
error to the graph's log (issue 39: it logged an ERROR with a traceback into the run's recording, and never ended).
In process, on a memory bus."""

from __future__ import annotations

import argparse
import io
import logging
import sys

import msgspec
import pytest

from messages import Text
from palpa.cli import topic as topic_cli
from palpa.cli.main import main
from palpa.node.node import Node
from palpa.runtime_msgs import LOG_TOPIC, LogRecord
from palpa.testing import GraphHarness


class ClosedPipe(io.StringIO):
    """A stdout whose reader has gone: every write fails as a closed pipe does."""

    def write(self, text: str) -> int:
        raise BrokenPipeError(32, "Broken pipe")


@pytest.mark.timeout(60)  # the deadline of a tool that would never end
def test_echo_into_a_closed_pipe_ends_quietly(monkeypatch: pytest.MonkeyPatch,
                                              caplog: pytest.LogCaptureFixture) -> None:
    graph = GraphHarness()
    graph.publish("chatter", Text(text="one"), latched=True)  # waiting for echo, as a late joiner gets it

    def tool_node(args: argparse.Namespace, name: str) -> Node:
        args.bus_where = "the memory bus"
        return Node(name=f"_{name}", transport=graph.bus.transport(), clock=graph.clock, heartbeat_s=0)

    monkeypatch.setattr(topic_cli, "tool_node", tool_node)
    monkeypatch.setattr(sys, "stdout", ClosedPipe())
    caplog.set_level(logging.DEBUG)
    try:
        assert main(["topic", "echo", "chatter", "--timeout", "0"]) == 0  # no count, no timeout: ends by the pipe
        graph.spin()
        logged = [msgspec.msgpack.decode(r.payload, type=LogRecord) for r in graph.raw if r.topic == LOG_TOPIC]
        assert logged == [] and not [r for r in caplog.records if r.levelno >= logging.WARNING]
    finally:
        graph.close()
