"""Pseudo-terminal plumbing shared by the serial device emulators.

A :class:`PtyDevice` plays the *device* side of a serial line: it owns the master end of a
pty, and the driver under test opens the slave end with plain pyserial, exactly as it would
open ``/dev/ttyUSB0``. Like udev's ``/dev/serial/by-id/...`` links, the device is reached
through a stable symlink (:attr:`PtyDevice.port`) that survives unplug/replug:

* ``unplug()`` closes the master (the driver's next read/write fails with EIO, as on a
  yanked USB adapter) and removes the symlink (opening it fails with ENOENT);
* ``replug()`` creates a *new* pty and re-points the same symlink at it.

One reader thread per device delivers incoming bytes to :meth:`PtyDevice.handle_line`
(split on CR or LF). Writes are non-blocking: when nobody drains the slave side the bytes
are dropped and counted, like a UART with no listener, so a streaming emulator never
blocks. Subclasses implement :meth:`handle_line` and call :meth:`write`.

Threading rule: only the reader thread closes the master fd while it runs (``unplug`` and
``stop`` ask it to and wait), so a select() never races against an fd number that another
part of the process has meanwhile reused.
"""

from __future__ import annotations

import contextlib
import errno
import os
import select
import signal
import tempfile
import threading
import tty
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import Self

_MAX_LINE = 4096  # bytes without a terminator before the partial input is discarded


class PtyDevice:
    """Device side of an emulated serial port, reachable through a stable symlink.

    Args:
        name: file name of the symlink (``by-id`` style), e.g. ``"palpa-fibre-daq"``.
        link_path: full symlink path; default ``/tmp/palpa-pty-XXXX/<name>`` (a fresh
            directory, so parallel tests never collide and paths stay short).
    """

    def __init__(self, name: str = "palpa-device", link_path: str | os.PathLike[str] | None = None) -> None:
        self._own_dir: Path | None = None
        if link_path is None:
            self._own_dir = Path(tempfile.mkdtemp(prefix="palpa-pty-", dir="/tmp"))
            link_path = self._own_dir / name
        self._link = Path(link_path)
        self._lock = threading.RLock()  # guards the fds and the plugged state
        self._master_fd: int | None = None
        self._slave_fd: int | None = None  # kept open so the master never sees EIO when the driver closes
        self._slave_name: str | None = None
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_w, False)
        self._stop = threading.Event()
        self._unplug_requested = False
        self._unplugged = threading.Event()
        self._thread: threading.Thread | None = None
        self._rx_buf = bytearray()
        self.bytes_dropped = 0  # bytes written while nobody was draining the slave side
        self.bytes_written = 0

    # -- lifecycle ---------------------------------------------------------------------

    @property
    def port(self) -> str:
        """The stable path a driver opens (a symlink to the current ``/dev/pts/N``)."""
        return str(self._link)

    @property
    def slave_name(self) -> str | None:
        """The current ``/dev/pts/N`` behind :attr:`port`, or None while unplugged."""
        with self._lock:
            return self._slave_name

    @property
    def plugged(self) -> bool:
        """True while the device is plugged in (the pty exists and the link points at it)."""
        with self._lock:
            return self._master_fd is not None

    def start(self) -> Self:
        """Create the pty and the symlink, and start the reader thread. Returns self."""
        if self._thread is not None:
            raise RuntimeError(f"PtyDevice {self.port} already started")
        self._plug()
        self._thread = threading.Thread(target=self._reader_loop, name=f"pty:{self._link.name}", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 2.0) -> None:
        """Stop the reader thread, close the pty and remove the symlink (idempotent)."""
        self._stop.set()
        self._wake()
        if self._thread is not None:
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                raise RuntimeError(f"PtyDevice {self.port}: reader thread did not stop within {timeout_s} s")
            self._thread = None
        with self._lock:
            self._close_fds()
        self._remove_link()
        for fd in (self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)
        self._wake_r = self._wake_w = -1
        if self._own_dir is not None:
            with contextlib.suppress(OSError):
                self._own_dir.rmdir()

    def __enter__(self) -> Self:
        return self.start() if self._thread is None else self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self.stop()

    def unplug(self, timeout_s: float = 2.0) -> None:
        """Simulate pulling the cable: close the master end and remove the symlink."""
        self._remove_link()
        if self._thread is None or not self._thread.is_alive():
            with self._lock:
                self._close_fds()
            self.on_unplug()
            return
        with self._lock:
            if self._master_fd is None:
                return
            self._unplugged.clear()
            self._unplug_requested = True
        self._wake()
        if not self._unplugged.wait(timeout_s):
            raise RuntimeError(f"PtyDevice {self.port}: reader thread did not release the pty within {timeout_s} s")
        self.on_unplug()

    def replug(self) -> None:
        """Simulate plugging the cable back in: a new pty behind the same symlink."""
        with self._lock:
            if self._master_fd is not None:
                raise RuntimeError(f"PtyDevice {self.port} is already plugged in")
            self._rx_buf.clear()
            self._plug()
        self._wake()
        self.on_replug()

    # -- I/O ---------------------------------------------------------------------------

    def write(self, data: bytes) -> bool:
        """Send bytes to the driver. Returns False (and counts the bytes) if they were dropped.

        Bytes are dropped while unplugged, and when the pty buffer is full because nobody
        reads the slave side (a real UART does not wait for its listener either).
        """
        with self._lock:
            fd = self._master_fd
            if fd is None:
                self.bytes_dropped += len(data)
                return False
            try:
                n = os.write(fd, data)
            except BlockingIOError:
                n = 0
            except OSError:
                n = 0
            self.bytes_written += n
            if n < len(data):
                self.bytes_dropped += len(data) - n
                return False
            return True

    def handle_line(self, line: bytes) -> None:
        """Called from the reader thread with each received line (terminator stripped).

        Empty lines are not delivered. Override in subclasses.
        """

    def handle_bytes(self, data: bytes) -> None:
        """Called from the reader thread with each received chunk; default: split on CR/LF."""
        for b in data:
            if b in (0x0D, 0x0A):
                if self._rx_buf:
                    line = bytes(self._rx_buf)
                    self._rx_buf.clear()
                    self.handle_line(line)
            else:
                self._rx_buf.append(b)
                if len(self._rx_buf) > _MAX_LINE:
                    self._rx_buf.clear()

    def on_unplug(self) -> None:
        """Hook run after an unplug (in the caller's thread). Override to reset state."""

    def on_replug(self) -> None:
        """Hook run after a replug (in the caller's thread). Override to emulate a reboot."""

    # -- internals ---------------------------------------------------------------------

    def _plug(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no CR/LF translation, no line discipline
        os.set_blocking(master, False)
        self._master_fd, self._slave_fd = master, slave
        self._slave_name = os.ttyname(slave)
        self._point_link(self._slave_name)

    def _point_link(self, target: str) -> None:
        # Atomic re-point: a driver polling the path never sees a half-made link.
        tmp = self._link.with_name(f".{self._link.name}.{os.getpid()}.tmp")
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        os.symlink(target, tmp)
        os.replace(tmp, self._link)

    def _remove_link(self) -> None:
        with contextlib.suppress(FileNotFoundError):
            self._link.unlink()

    def _close_fds(self) -> None:
        for fd in (self._master_fd, self._slave_fd):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master_fd = self._slave_fd = None
        self._slave_name = None

    def _wake(self) -> None:
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"x")

    def _reader_loop(self) -> None:
        while not self._stop.is_set():
            with self._lock:
                if self._unplug_requested:
                    self._close_fds()
                    self._unplug_requested = False
                    self._unplugged.set()
                fd = self._master_fd
            fds = [self._wake_r] if fd is None else [self._wake_r, fd]
            try:
                readable, _, _ = select.select(fds, [], [], 0.5)
            except (OSError, ValueError):
                continue
            if self._wake_r in readable:
                with contextlib.suppress(OSError):
                    os.read(self._wake_r, 4096)
            if fd is not None and fd in readable:
                try:
                    data = os.read(fd, 4096)
                except BlockingIOError:
                    continue
                except OSError as exc:
                    if exc.errno == errno.EIO:  # no slave open at all; avoid spinning
                        self._stop.wait(0.02)
                    continue
                if data:
                    self.handle_bytes(data)


def serve_until_signal(device: PtyDevice, on_tick: Callable[[], None] | None = None, tick_s: float = 1.0) -> int:
    """Command-line main loop: start ``device``, print its port, run until SIGINT/SIGTERM.

    Handlers are installed explicitly: a background job of a non-interactive shell starts
    with SIGINT ignored, and a launcher stops its children with SIGTERM; either way the
    emulator removes its symlink on the way out. ``on_tick`` runs every ``tick_s``.
    Returns the exit status (0).
    """
    stop = threading.Event()

    def _on_signal(_signum: int, _frame: object) -> None:
        stop.set()

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _on_signal)
    with device:
        print(device.port, flush=True)
        while not stop.wait(tick_s):
            if on_tick is not None:
                on_tick()
    return 0
