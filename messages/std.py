"""General-purpose messages."""

from __future__ import annotations

from palpa.message import Message


class Text(Message, frozen=True, kw_only=True):
    """A line of text (the talker/listener example, operator notes)."""

    text: str
    stamp_ns: int = 0
