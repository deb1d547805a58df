"""Keys and sockets (issue 22): private secret keys, private ipc sockets, loopback parsed properly, CURVE refusals
logged on both sides and client keys reloaded while the bus runs."""

from __future__ import annotations

import os
import signal
import stat
from pathlib import Path

import pytest

import palpa
from messages import Text
from palpa.cli.main import main
from palpa.errors import BusError
from palpa.net.address import BusAddress, default_address, private_dir
from palpa.net.bus import Bus, is_loopback_endpoint
from palpa.net.keys import load_secret_key
from palpa.net.transport import ZmqTransport
from tests.procs import ProcessGroup, palpa_cmd, wait_until


@pytest.mark.parametrize(("endpoint", "loopback"), [
    ("tcp://127.0.0.1:5555", True), ("tcp://127.3.2.1:*", True), ("tcp://localhost:5555", True),
    ("tcp://[::1]:5555", True), ("ipc:///tmp/x", True),
    ("tcp://localhost.example.com:5555", False), ("tcp://127.0.0.1.nip.io:5555", False),
    ("tcp://localhostile:5555", False), ("tcp://0.0.0.0:5555", False), ("tcp://10.0.0.1:5555", False),
    ("tcp://[::]:5555", False), ("tcp://*:5555", False),
])
def test_is_loopback_endpoint_parses_the_host(endpoint: str, loopback: bool) -> None:
    assert is_loopback_endpoint(endpoint) is loopback


def test_keygen_writes_a_private_secret_and_loading_refuses_a_readable_one(tmp_path: Path) -> None:
    assert main(["keygen", str(tmp_path), "node"]) == 0
    secret = tmp_path / "node.key_secret"
    assert stat.S_IMODE(secret.stat().st_mode) == 0o600
    assert stat.S_IMODE((tmp_path / "node.key").stat().st_mode) == 0o644
    public, key = load_secret_key(secret)
    assert len(public) == len(key) == 40
    secret.chmod(0o644)
    with pytest.raises(BusError, match=r"accessible by others \(mode 0644\); run: chmod 600"):
        load_secret_key(secret)
    with pytest.raises(BusError, match="accessible by others"):
        Bus(BusAddress("tcp://127.0.0.1:*", "tcp://127.0.0.1:*", "tcp://127.0.0.1:*"),
            curve=palpa.net.bus.CurveServer(secret, tmp_path)).start()


def test_keygen_refuses_to_overwrite_a_pair_unless_forced(tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["keygen", str(tmp_path), "server"]) == 0
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    capsys.readouterr()
    assert main(["keygen", str(tmp_path), "server"]) == 1
    err = capsys.readouterr().err
    assert "server.key" in err and "already exist" in err and "--force" in err and len(err.splitlines()) == 1
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
    (tmp_path / "server.key").unlink()  # half a pair is refused too: its secret is someone's
    assert main(["keygen", str(tmp_path), "server"]) == 1
    assert (tmp_path / "server.key_secret").read_bytes() == before["server.key_secret"]
    assert main(["keygen", str(tmp_path), "server", "--force"]) == 0
    assert (tmp_path / "server.key_secret").read_bytes() != before["server.key_secret"]
    assert stat.S_IMODE((tmp_path / "server.key_secret").stat().st_mode) == 0o600


@pytest.mark.system
def test_ipc_sockets_live_in_a_checked_private_directory(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    runtime = tmp_path / "run"
    runtime.mkdir(mode=0o700)
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(runtime))
    assert private_dir() == runtime / "palpa" and default_address() == f"ipc://{runtime}/palpa/bus"
    assert stat.S_IMODE((runtime / "palpa").stat().st_mode) == 0o700
    with Bus(BusAddress.parse(f"ipc://{runtime}/palpa/t")) as bus:
        assert bus.address is not None
        for ep in (bus.address.pub, bus.address.sub, bus.address.latch):
            assert stat.S_IMODE(os.stat(ep[len("ipc://"):]).st_mode) == 0o600
    (runtime / "palpa").chmod(0o755)  # opened to others (or made by someone else): refused, named
    with pytest.raises(BusError, match=r"palpa is not a private directory .* mode 0755"):
        private_dir()
    runtime.chmod(0o755)  # an XDG_RUNTIME_DIR others may enter is not used at all
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(runtime))
    assert private_dir() == Path(f"/tmp/palpa-{os.getuid()}")


@pytest.mark.system
def test_a_node_refuses_another_users_ipc_socket(tmp_path: Path) -> None:
    if os.getuid() != 0:
        pytest.skip("needs root to make a socket owned by another user")
    base = f"/tmp/pk-{os.getpid()}"
    with Bus(BusAddress.parse(f"ipc://{base}")) as bus:
        assert bus.address is not None
        os.chown(base + ".pub", 65534, 65534)  # as if user nobody had bound it first
        with pytest.raises(BusError, match="belongs to uid 65534, not to this user"):
            ZmqTransport(bus.address)


@pytest.mark.system
def test_curve_refusals_are_logged_on_both_sides_and_sighup_lets_a_new_key_in(
        tmp_path: Path, procs: ProcessGroup, caplog: pytest.LogCaptureFixture) -> None:
    from palpa.net.keys import create_key_pair

    keys, clients = tmp_path / "keys", tmp_path / "clients"
    clients.mkdir()
    for who in ("server", "good", "late"):
        create_key_pair(keys, who)
    (clients / "good.key").write_bytes((keys / "good.key").read_bytes())
    bus = procs.start(palpa_cmd("bus", "--tcp", "127.0.0.1", "--curve-secret", str(keys / "server.key_secret"),
                                "--curve-clients", str(clients)))
    address = BusAddress.parse(bus.wait_for_output("palpa bus ready", 10).split("ready ", 1)[1])

    def make(name: str, who: str) -> palpa.Node:
        old = dict(os.environ)
        os.environ.update(PALPA_BUS_SERVER_KEY=str(keys / "server.key"),
                          PALPA_CURVE_SECRET=str(keys / f"{who}.key_secret"))
        try:
            return palpa.Node(name=name, bus=address, heartbeat_s=0)
        finally:
            os.environ.clear()
            os.environ.update(old)

    with make("good_pub", "good") as pub_node:
        with caplog.at_level("ERROR", logger="palpa.net.transport"):
            late = make("late_sub", "late")
        assert "refused this node's handshake (authentication refused)" in caplog.text
        bus.wait_for_output("CURVE: refused a client with unknown public key", 10)
        sub = late.subscribe("secret", Text)
        pub = pub_node.publisher("secret", Text)
        for _ in range(10):
            pub.publish(Text(text="x"))
            late.spin_once(0.02)
        assert sub.stats.received == 0
        (clients / "late.key").write_bytes((keys / "late.key").read_bytes())
        bus.signal(signal.SIGHUP)
        bus.wait_for_output("reloaded 2 client key(s)", 10)
        try:  # ZeroMQ reconnects by itself (every 2 s at most)
            wait_until(lambda: sub.next(0.05) is not None, 20, "the admitted client to hear the publisher",
                       step=lambda: pub.publish(Text(text="now you may")))
        except AssertionError as exc:
            raise AssertionError(f"{exc}:\n{bus.output()}") from None
        late.close(0)
    assert bus.stop(5) == 0
