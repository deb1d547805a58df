"""``memq://NAME``: an in-memory bus of the process selected by address (as LCM's), so a node built without a
transport joins an executor running on that bus (issue 38)."""

from __future__ import annotations

import pytest

from messages import Text
from palpa import env as palpa_env
from palpa.errors import BusError
from palpa.net.address import BusAddress
from palpa.net.memory import MemoryTransport, memq_name, named_bus
from palpa.node.node import Node
from palpa.testing import GraphHarness


class _Echo(Node):
    """Answers every ``ping`` with the same text on ``pong``."""

    def setup(self) -> None:
        pong = self.publisher("pong", Text)
        self.subscribe("ping", Text, lambda m: pong.publish(Text(text=m.text)))


def test_a_node_built_on_a_memq_address_joins_the_executor_on_that_named_bus() -> None:
    with GraphHarness(bus=named_bus("test-memq-a")) as g:
        node = _Echo(name="echo", bus="memq://test-memq-a", clock=g.clock, heartbeat_s=0)
        assert isinstance(node.transport, MemoryTransport)
        g.composition.adopt(node)
        g.publish("ping", Text(text="hello"))
        assert [m.text for m in g.published("pong")] == ["hello"]


def test_memq_names_separate_buses(monkeypatch: pytest.MonkeyPatch) -> None:
    """Under PALPA_BUS=memq://NAME a node with no bus given joins NAME; another name is another bus."""
    monkeypatch.setenv(palpa_env.BUS, "memq://test-memq-c")
    with GraphHarness(bus=named_bus("test-memq-b")) as g:
        node = _Echo(name="echo", clock=g.clock, heartbeat_s=0)
        assert isinstance(node.transport, MemoryTransport) and node.transport.bus is named_bus("test-memq-c")
        g.composition.adopt(node)
        g.publish("ping", Text(text="hello"))
        assert g.published("pong") == []


def test_memq_without_a_name_and_memq_for_a_tool_say_why() -> None:
    assert memq_name("ipc:///tmp/x") is None
    assert memq_name("memq://x") == "x"
    with pytest.raises(BusError, match="memq:// needs a name"):
        _Echo(name="echo", bus="memq://", heartbeat_s=0)
    with pytest.raises(BusError, match="a launch or a tool needs ipc:// or tcp://"):
        BusAddress.parse("memq://x")
