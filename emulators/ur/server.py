"""Sockets and threads of the emulator: dashboard (29999), script (30003), RTDE (30004).

Threads: one acceptor (selector over the three listening sockets), one controller thread
(2 ms ticks, RTDE streaming), one reader per client connection. Socket writes of replies are
blocking; streamed data packages are sent without blocking and dropped while the client lags,
as a controller skips packages it cannot send.
"""

from __future__ import annotations

import contextlib
import logging
import selectors
import socket
import struct
import threading
import time
from collections.abc import Callable
from types import TracebackType

from emulators.clock_file import ClockReader
from emulators.ur.controller import ControllerConfig, FaultPlan, SurfaceLike, UrController
from emulators.ur.dashboard import WELCOME
from emulators.ur.dashboard import reply as dashboard_reply
from emulators.ur.rtde import HEADER, RtdeSession
from emulators.ur.script import ScriptReceiver
from emulators.ur.stepper import ControllerClock
from models.arm import TICK_S

_LOG = logging.getLogger("palpa.urfake")
_MAX_CATCHUP_TICKS = 50
_TICKS_PER_LOCK = 5
_MIN_PAUSE_S = 0.0002
_JOIN_TIMEOUT_S = 3.0


class _Conn:
    """A client connection. `close` may be called from any thread; it only shuts the socket
    down, and the connection's reader thread closes it."""

    def __init__(self, sock: socket.socket, kind: str) -> None:
        self.sock, self.kind = sock, kind
        self.lock = threading.Lock()
        self.closed = False
        self._backlog = b""

    def send(self, data: bytes) -> None:
        with self.lock:
            if self.closed:
                return
            try:
                if self._backlog:
                    self.sock.sendall(self._backlog)
                    self._backlog = b""
                self.sock.sendall(data)
            except OSError:
                self.close()

    def send_stream(self, data: bytes) -> None:
        with self.lock:
            if self.closed:
                return
            try:
                if self._backlog:
                    n = self._send_nowait(self._backlog)
                    self._backlog = self._backlog[n:]
                    if self._backlog:
                        return  # client is lagging: drop this package
                n = self._send_nowait(data)
                self._backlog = data[n:]
            except OSError:
                self.close()

    def _send_nowait(self, data: bytes) -> int:
        try:
            return self.sock.send(data, socket.MSG_DONTWAIT)
        except BlockingIOError:
            return 0

    def close(self) -> None:
        self.closed = True
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)


class UrEmulator:
    """A UR e-Series controller on `host` (any loopback address), good enough for ur_rtde.

    `start()` returns once all three ports are listening; use as a context manager to have
    every thread stopped and joined on exit. Pass port 0 to let the OS choose (then see
    `ports`); ur_rtde itself always connects to 29999/30003/30004.

    The controller runs on the wall clock. With `clock` (emulators.clock_file) the arm's motion also
    never runs more than `clock_lead_s` ahead of that clock: the arm holds where it is while the
    clock's owner stalls. Only the motion holds: the controller's programs, registers, watchdog and
    RTDE streams go on, so that a client blocked in a handshake (ur_rtde's path upload waits for
    the new script to run) is answered while nobody advances the clock.
    """

    def __init__(self, host: str = "127.0.0.1", *, dashboard_port: int = 29999, script_port: int = 30003,
                 rtde_port: int = 30004, config: ControllerConfig | None = None,
                 phantom: SurfaceLike | None = None, faults: FaultPlan | None = None,
                 log: Callable[[str], None] | None = None, clock: ClockReader | None = None,
                 clock_lead_s: float = 0.1) -> None:
        if not clock_lead_s >= 0:
            raise ValueError(f"UrEmulator: clock_lead_s must be >= 0, got {clock_lead_s}")
        self.host = host
        self.ports = {"dashboard": dashboard_port, "script": script_port, "rtde": rtde_port}
        self.controller = UrController(config, phantom, log or _LOG.info)
        self.controller.on_drop = self._drop
        self.controller.arm_faults(faults)
        self._listeners: dict[str, socket.socket] = {}
        self._conns: list[_Conn] = []
        self._sessions: list[tuple[_Conn, RtdeSession]] = []
        self._threads: list[threading.Thread] = []
        self._stop = threading.Event()
        self._wake_r, self._wake_w = socket.socketpair()
        self._refuse_until = 0.0
        self._guard = threading.Lock()  # protects _conns, _sessions, _threads
        self._clock, self._lead_ticks = clock, round(clock_lead_s / TICK_S)
        self._clock_base: tuple[int, int] | None = None  # (clock ns, arm steps) when the clock was first read
        self._clock_failed = False

    # ------------------------------------------------------------- lifecycle
    def start(self) -> UrEmulator:
        try:
            for kind, port in self.ports.items():
                s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
                s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                try:
                    s.bind((self.host, port))
                except OSError as e:
                    s.close()
                    raise OSError(f"UR emulator: cannot listen on {self.host}:{port} ({kind}): {e}") from e
                s.listen(8)
                self._listeners[kind] = s
                self.ports[kind] = s.getsockname()[1]
        except OSError:
            self._close_listeners()
            raise
        self._spawn(self._accept_loop, "urfake-accept")
        self._spawn(self._tick_loop, "urfake-controller")
        self.controller.log(f"listening on {self.host} ports {self.ports}")
        return self

    def stop(self) -> None:
        """Close every socket and join every thread (each join bounded)."""
        self._stop.set()
        with contextlib.suppress(OSError):
            self._wake_w.send(b"x")
        joined: set[threading.Thread] = set()
        while True:  # a connection accepted just before the stop may spawn one more reader
            with self._guard:
                conns, threads = list(self._conns), [t for t in self._threads if t not in joined]
            if not threads:
                break
            for c in conns:
                c.close()
            for t in threads:
                if t is not threading.current_thread():
                    t.join(_JOIN_TIMEOUT_S)
                joined.add(t)
        threads = list(joined)
        self._close_listeners()
        self._wake_r.close()
        self._wake_w.close()
        stuck = [t.name for t in threads if t.is_alive()]
        if stuck:
            raise RuntimeError(f"UR emulator on {self.host}: threads did not stop: {stuck}")

    def __enter__(self) -> UrEmulator:
        return self.start()

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop()

    def threads_alive(self) -> list[str]:
        with self._guard:
            return [t.name for t in self._threads if t.is_alive()]

    # ------------------------------------------------------- fault injection
    def protective_stop(self, reason: str = "injected by test") -> None:
        with self.controller.lock:
            self.controller.protective_stop(reason)

    def unlock_protective_stop(self) -> str:
        with self.controller.lock:
            return self.controller.unlock_protective_stop()

    def drop_connections(self, refuse_s: float = 0.0) -> None:
        """Close every client connection; refuse new ones for `refuse_s` seconds."""
        with self.controller.lock:
            self.controller.log(f"dropping all connections (refusing for {refuse_s} s)")
        self._drop(refuse_s)

    def pause_streaming(self, duration_s: float) -> None:
        with self.controller.lock:
            self.controller.pause_streaming(duration_s)

    def set_remote_control(self, enabled: bool) -> None:
        with self.controller.lock:
            self.controller.remote_control = enabled

    def arm_faults(self, plan: FaultPlan | None) -> None:
        with self.controller.lock:
            self.controller.arm_faults(plan)

    # ------------------------------------------------------------ inspection
    @property
    def pose_mm(self) -> tuple[float, ...]:
        with self.controller.lock:
            return self.controller.arm.pose

    @property
    def client_count(self) -> int:
        with self._guard:
            return sum(1 for c in self._conns if not c.closed)

    def wait_until(self, condition: Callable[[UrController], bool], timeout_s: float) -> bool:
        """Poll `condition(controller)` (under the lock) every 5 ms until true or timeout."""
        deadline = time.monotonic() + timeout_s
        while True:
            with self.controller.lock:
                if condition(self.controller):
                    return True
            if time.monotonic() >= deadline:
                return False
            self._stop.wait(0.005)

    # -------------------------------------------------------------- internals
    def _spawn(self, target: Callable[..., None], name: str, *args: object) -> None:
        t = threading.Thread(target=target, args=args, name=name, daemon=True)
        with self._guard:
            self._threads = [x for x in self._threads if x.is_alive()]
            self._threads.append(t)
        t.start()

    def _close_listeners(self) -> None:
        for s in self._listeners.values():
            s.close()
        self._listeners.clear()

    def _drop(self, refuse_s: float) -> None:
        self._refuse_until = time.monotonic() + refuse_s
        with self._guard:
            conns = list(self._conns)
        for c in conns:
            c.close()

    def _accept_loop(self) -> None:
        sel = selectors.DefaultSelector()
        try:
            for kind, s in self._listeners.items():
                sel.register(s, selectors.EVENT_READ, kind)
            sel.register(self._wake_r, selectors.EVENT_READ, None)
            while not self._stop.is_set():
                for key, _ in sel.select():
                    if key.data is None:
                        continue
                    try:
                        sock, peer = key.fileobj.accept()  # type: ignore[union-attr]
                    except OSError:
                        continue
                    if time.monotonic() < self._refuse_until:
                        sock.close()
                        continue
                    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                    conn = _Conn(sock, key.data)
                    with self._guard:
                        self._conns.append(conn)
                    self._spawn(self._serve, f"urfake-{key.data}-{peer[1]}", conn)
        finally:
            sel.close()

    def _serve(self, conn: _Conn) -> None:
        try:
            {"dashboard": self._serve_dashboard, "script": self._serve_script, "rtde": self._serve_rtde}[conn.kind](conn)
        except OSError:
            pass
        finally:
            conn.close()
            with self._guard:
                self._conns = [c for c in self._conns if c is not conn]
                self._sessions = [(c, s) for c, s in self._sessions if c is not conn]
            conn.sock.close()

    def _serve_dashboard(self, conn: _Conn) -> None:
        conn.send((WELCOME + "\n").encode())
        buf = b""
        while not conn.closed:
            data = conn.sock.recv(4096)
            if not data:
                return
            buf += data
            while b"\n" in buf:
                line, buf = buf.split(b"\n", 1)
                with self.controller.lock:
                    answer, close = dashboard_reply(self.controller, line.decode(errors="replace"))
                conn.send((answer + "\n").encode())
                if close:
                    return

    def _serve_script(self, conn: _Conn) -> None:
        receiver = ScriptReceiver()
        while not conn.closed:
            data = conn.sock.recv(65536)
            if not data:
                return
            units = list(receiver.feed(data.decode(errors="replace")))
            with self.controller.lock:
                for kind, text in units:
                    if kind == "program":
                        self.controller.submit_program(text)
                    else:
                        self.controller.run_statement(text)

    def _serve_rtde(self, conn: _Conn) -> None:
        ctl = self.controller
        session = RtdeSession(ctl.config.controller_version, ctl.getter, ctl.write_inputs, ctl.log)
        with self._guard:
            self._sessions.append((conn, session))
        while not conn.closed:
            header = self._recv_exact(conn, HEADER.size)
            if header is None:
                return
            size, msg_type = HEADER.unpack(header)
            payload = self._recv_exact(conn, size - HEADER.size) if size > HEADER.size else b""
            if payload is None:
                return
            with ctl.lock:
                try:
                    replies = session.handle(msg_type, payload, ctl.ticks)
                except (struct.error, ValueError, KeyError) as e:
                    ctl.log(f"RTDE: malformed message type {msg_type}: {e}")
                    replies = []
            for r in replies:
                conn.send(r)

    @staticmethod
    def _recv_exact(conn: _Conn, n: int) -> bytes | None:
        buf = b""
        while len(buf) < n:
            data = conn.sock.recv(n - len(buf))
            if not data:
                return None
            buf += data
        return buf

    def _motion_to(self) -> int | None:
        """How many arm steps the external clock allows by now (its time since first read, plus the lead), or
        None while the arm moves on the wall clock alone (no clock, or none written yet, or released)."""
        try:
            now = self._clock.read() if self._clock is not None else None
        except (RuntimeError, ValueError) as e:  # the arm runs on the wall clock rather than stop for good
            if not self._clock_failed:
                self.controller.log(f"external clock unreadable, the arm follows the wall clock: {e}")
            self._clock_failed, now = True, None
        else:
            self._clock_failed = False  # readable again: a later failure is logged again
        if now is None:
            self._clock_base = None  # released: a clock written again is followed from where it is then
            return None
        if self._clock_base is None:
            self._clock_base = (now, self.controller.arm_steps)
        ns0, steps0 = self._clock_base
        return steps0 + int((now - ns0) / (TICK_S * 1e9)) + self._lead_ticks

    def _tick_loop(self) -> None:
        ctl = self.controller
        stepper = ControllerClock(ctl, time.monotonic_ns, max_catchup=_MAX_CATCHUP_TICKS)
        while not self._stop.is_set():
            n = stepper.step(self._motion_to(), batch=_TICKS_PER_LOCK, between=lambda: time.sleep(0))
            with ctl.lock:
                paused = ctl.ticks < ctl.stream_paused_until
                with self._guard:
                    sessions = list(self._sessions)
                due = [] if paused or n == 0 else [(c, s.due_packages(ctl.ticks)) for c, s in sessions]
            for conn, packages in due:
                for p in packages:
                    conn.send_stream(p)
            # never spin: even when late, give the reader threads a moment to take the lock
            self._stop.wait(max(_MIN_PAUSE_S, (stepper.next_due_ns() - time.monotonic_ns()) / 1e9))
