"""palpa.targets: the one loader of user code by name (node targets, message modules)."""

from __future__ import annotations

import pytest

from palpa import env as palpa_env
from palpa.targets import TargetError, load_node_class, message_modules


def test_message_modules_come_from_the_entry_point_group_then_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(palpa_env.MESSAGES, "my_lab.msgs, messages")
    assert message_modules() == ["messages", "my_lab.msgs"]  # this project's pyproject declares `messages`


@pytest.mark.parametrize(("target", "says"), [
    ("nodes.demo", "expected package.module:Class"),
    ("no_such_pkg.mod:Node", "cannot import module 'no_such_pkg.mod'"),
    ("nodes.demo:Talkr", "module 'nodes.demo' has no 'Talkr' (did you mean 'Talker'?)"),
    ("json:JSONDecoder", "'json:JSONDecoder' is not a palpa.Node subclass"),
])
def test_a_target_that_does_not_load_says_which_part_failed(target: str, says: str) -> None:
    with pytest.raises(TargetError) as info:
        load_node_class(target)
    assert says in str(info.value) and str(info.value).count(repr(target)) == 1


def test_a_node_target_loads() -> None:
    from nodes.demo import Talker

    assert load_node_class("nodes.demo:Talker") is Talker
