"""The endpoints a node hands out: publishers, subscriptions, timers, and the raw envelope type.

They get what they use and no more: a publisher the transport, the clock and the node's :class:`~palpa.node.dispatch.Dispatch`
(to batch inside callbacks), and a :class:`~palpa.node.dispatch.Spinner` for its blocking wait; a subscription only the
spinner. Create them through ``Node.publisher``, ``Node.subscribe`` and ``Node.timer``, not directly.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from typing import Any, Generic, NamedTuple, TypeVar, get_type_hints

import msgspec

from palpa.message import Message
from palpa.net.transport import Transport
from palpa.net.wire import Header, HeaderTemplate, TopicStats, msgpack_array
from palpa.node.dispatch import Dispatch, Spinner
from palpa.timing.clock import Clock

__all__ = ["DEFAULT_BATCH", "MsgInfo", "Publisher", "RawMessage", "Subscription", "Timer", "handler_type",
           "wants_info"]

M = TypeVar("M", bound=Message)
DEFAULT_BATCH = 64
"""Messages a publisher coalesces at most into one ZeroMQ message while inside a callback."""

_encoder = msgspec.msgpack.Encoder()


class RawMessage(msgspec.Struct, frozen=True, gc=False):
    """An envelope delivered undecoded (recorder, ``topic echo``): the payload bytes exactly as received."""

    topic: str
    header: Header
    payload: bytes
    blobs: list[bytes]
    from_cache: bool
    recv_ns: int


class MsgInfo(NamedTuple):
    """What came with a message besides its payload, handed to a callback that asks for it: ``def on_image(self,
    msg: Image, info: palpa.MsgInfo)`` (the publisher, sequence number and stamp in ``header``, binary ``blobs``)."""

    header: Header
    blobs: list[bytes]
    from_cache: bool
    """True when it came from the latched cache (a value published before this node subscribed)."""


class Publisher(Generic[M]):
    """Publishes one message type on one topic; ``publish`` returns the sequence number it used.

    Batching: messages published from inside a callback or timer are coalesced (up to ``batch`` per ZeroMQ
    message) and leave when the callback returns, so a burst costs one send and a single message no extra
    latency. Outside callbacks each publish is sent at once, unless the publisher was made with an explicit
    ``batch`` (then call :meth:`flush`, or let the node's loop do it).
    """

    def __init__(
        self, transport: Transport, clock: Clock, dispatch: Dispatch, spinner: Spinner, origin: tuple[str, int],
        topic: str, msg_type: type[M], latched: bool, batch: int | None, direct: bool | None,
        instant: bool = False,
    ) -> None:
        """``origin`` is the node's (name, incarnation) written into every header; ``instant``: the clock is a
        simulation's, and every header says which instant it was at (``Header.at``)."""
        self._transport = transport
        self._clock = clock
        self._dispatch = dispatch
        self._spinner = spinner
        self.topic = topic
        self.type = msg_type
        self.latched = latched
        self.seq = 0
        self.batch = 1 if latched else max(1, DEFAULT_BATCH if batch is None else batch)
        self._always_batch = batch is not None and self.batch > 1
        self._topic_b = topic.encode()
        self._type_name = msg_type.type_name
        self._header = HeaderTemplate(self._type_name, origin[0], latched, origin[1], instant)
        self._pending_headers: list[bytes] = []
        self._pending_payloads: list[bytes] = []
        self._send = transport.sender(self._topic_b, direct)
        self.direct = self._send != transport.send
        """Whether this topic goes straight to its subscribers (the transport may have refused ``direct``)."""

    @property
    def has_subscribers(self) -> bool:
        """True once some subscriber's subscription for this topic has reached this node (ZeroMQ drops what is
        published before that)."""
        return self._transport.has_subscribers(self._topic_b)

    def wait_for_subscribers(self, timeout_s: float) -> bool:
        """Spin the node until :attr:`has_subscribers` or ``timeout_s`` passes; returns whether someone listens."""
        deadline = time.monotonic() + timeout_s
        while not self.has_subscribers:
            remaining = deadline - time.monotonic()
            if remaining <= 0 or self._spinner.is_shutdown:
                return False
            self._spinner.spin_once(min(0.01, remaining))
        return True

    def publish(self, msg: M, *, blobs: Sequence[bytes] = (), stamp_ns: int | None = None) -> int:
        """Serialise and send ``msg`` (plus optional binary blobs). ``stamp_ns`` defaults to the node clock."""
        if type(msg) is not self.type:
            raise TypeError(
                f"publisher {self.topic!r} carries {self._type_name}, not {type(msg).__name__}"
            )
        # everything that can fail (an unencodable field, a bad stamp) fails before any state changes, so a
        # failed publish never leaves a header without its payload in the batch
        payload = _encoder.encode(msg)
        now = self._clock.now_ns()
        header = self._header.pack(self.seq + 1, now if stamp_ns is None else stamp_ns, now)
        self.seq = seq = self.seq + 1
        if self.batch > 1 and (self._dispatch.depth or self._always_batch) and not blobs:
            if not self._pending_headers:
                self._dispatch.pending(self)
            self._pending_headers.append(header)
            self._pending_payloads.append(payload)
            if len(self._pending_headers) >= self.batch:
                self.flush()
            return seq
        if self._pending_headers:
            self.flush()
        frames = [self._topic_b, header, payload]
        if blobs:
            frames.extend(blobs)
        self._send(frames, self.latched)
        return seq

    def flush(self) -> None:
        """Send batched messages now (the node also flushes after every callback and timer)."""
        headers = self._pending_headers
        if not headers:
            return
        if len(headers) == 1:
            frames = [self._topic_b, headers[0], self._pending_payloads[0]]
        else:
            frames = [self._topic_b, msgpack_array(headers), msgpack_array(self._pending_payloads)]
        self._pending_headers = []
        self._pending_payloads = []
        self._send(frames, False)


class Subscription(Generic[M]):
    """A typed subscription. With a callback, messages are handed to it; without, iterate it (or ``next()``)."""

    def __init__(
        self,
        spinner: Spinner,
        topic: str,
        msg_type: type[M],
        callback: Callable[[M], object] | Callable[[M, MsgInfo], object] | None,
        queue_size: int,
    ) -> None:
        """``callback`` gets ``(msg)``, or ``(msg, info)`` when a parameter is annotated :class:`MsgInfo`."""
        self._spinner = spinner
        self.topic = topic
        self.type = msg_type
        self.callback: Callable[..., object] | None = callback
        self.with_info = callback is not None and wants_info(callback)
        """Whether the callback takes ``(msg, info)``."""
        self.stats = TopicStats()
        self.queue: deque[M] = deque(maxlen=queue_size)
        self.last_header: Header | None = None
        self.last_blobs: list[bytes] = []
        self.type_name = msg_type.type_name
        self.decoder = msgspec.msgpack.Decoder(msg_type)
        self.batch_decoder = msgspec.msgpack.Decoder(list[msg_type])  # type: ignore[valid-type]

    def next(self, timeout_s: float | None = None) -> M | None:
        """The next message, spinning the node while waiting; None on timeout or shutdown."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while not self.queue:
            if self._spinner.is_shutdown:
                return None
            remaining = 0.1 if deadline is None else min(0.1, deadline - time.monotonic())
            if remaining <= 0:
                return None
            self._spinner.spin_once(remaining)
        return self.queue.popleft()

    def __iter__(self) -> Iterator[M]:
        return self

    def __next__(self) -> M:
        msg = self.next()
        if msg is None:
            raise StopIteration
        return msg


class Timer:
    """A periodic (or one-shot) callback on the node's clock."""

    def __init__(self, period_ns: int, callback: Callable[[], object], due_ns: int, oneshot: bool) -> None:
        self.period_ns = period_ns
        self.callback = callback
        self.due_ns = due_ns
        self.oneshot = oneshot
        self.cancelled = False
        self.running = False

    def cancel(self) -> None:
        self.cancelled = True


def wants_info(callback: Callable[..., object]) -> bool:
    """Whether ``callback`` has a parameter annotated :class:`MsgInfo` (then it is called as ``(msg, info)``)."""
    try:
        hints: dict[str, Any] = get_type_hints(callback)
    except Exception:  # unresolvable annotations: the plain form
        return False
    return any(h is MsgInfo for k, h in hints.items() if k != "return")


def handler_type(callback: Callable[..., object]) -> type[Message]:
    try:
        hints = get_type_hints(callback)
    except Exception as exc:  # unresolvable annotations
        raise TypeError(f"cannot read the message type of {callback!r}: {exc}") from None
    hints.pop("return", None)
    for hint in hints.values():
        if isinstance(hint, type) and issubclass(hint, Message):
            return hint
    raise TypeError(
        f"{getattr(callback, '__qualname__', callback)!r} has no Message-typed parameter: annotate it "
        "or pass the type explicitly: subscribe(topic, Type, callback)"
    )


