"""Linux network namespaces as stand-in hosts (issue 22): ``count`` namespaces, each with one veth end on a bridge
that lives in a namespace of its own, so nothing touches the machine's own network. Used by
tests/test_multihost.py and bench/multihost.py; docs/multihost.md shows the same commands by hand.

Needs root and iproute2's ``ip``; :func:`why_no_netns` says why not when they are missing. :meth:`Hosts.down`
deletes every namespace it made (which deletes their veth ends), whatever happened.
"""

from __future__ import annotations

import os
import secrets
import shutil
import subprocess

__all__ = ["Hosts", "why_no_netns"]


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, timeout=10)


def why_no_netns() -> str:
    """Why network namespaces cannot be made here, or "" when they can (tried once, then deleted)."""
    if shutil.which("ip") is None:
        return "iproute2 'ip' is not installed"
    if os.geteuid() != 0:
        return "network namespaces need root (ip netns add)"
    probe = f"p22q{secrets.token_hex(3)}"
    try:
        _ip("netns", "add", probe)
        _ip("netns", "del", probe)
    except (subprocess.CalledProcessError, OSError) as exc:
        return f"ip netns is not usable here: {exc}"
    return ""


class Hosts:
    """Namespaces ``<tag>h1..hN`` with one veth each onto a bridge in namespace ``<tag>br``; host i is
    10.<a>.<b>.i on a /24 of its own (random, so concurrent runs do not collide)."""

    def __init__(self, count: int) -> None:
        self.tag = f"p{secrets.token_hex(3)}"  # interface names stay under 15 characters
        self.subnet = f"10.{secrets.randbelow(200) + 20}.{secrets.randbelow(250) + 1}"
        self.bridge = f"{self.tag}br"
        self.names = [f"{self.tag}h{i}" for i in range(1, count + 1)]
        self.made: list[str] = []

    def up(self) -> None:
        """Make the bridge and the hosts (on failure, :meth:`down` still removes what was made)."""
        _ip("netns", "add", self.bridge)
        self.made.append(self.bridge)
        _ip("-n", self.bridge, "link", "add", "br0", "type", "bridge")
        _ip("-n", self.bridge, "link", "set", "br0", "up")
        for i, ns in enumerate(self.names, 1):
            _ip("netns", "add", ns)
            self.made.append(ns)
            _ip("-n", ns, "link", "set", "lo", "up")
            inner, outer = f"{self.tag}a{i}", f"{self.tag}b{i}"
            _ip("link", "add", inner, "type", "veth", "peer", "name", outer)
            _ip("link", "set", inner, "netns", ns)
            _ip("link", "set", outer, "netns", self.bridge)
            _ip("-n", ns, "addr", "add", f"{self.addr(i)}/24", "dev", inner)
            _ip("-n", ns, "link", "set", inner, "up")
            _ip("-n", self.bridge, "link", "set", outer, "master", "br0")
            _ip("-n", self.bridge, "link", "set", outer, "up")

    def __enter__(self) -> Hosts:
        """:meth:`up` (what it made is deleted again if it fails half-way)."""
        try:
            self.up()
        except BaseException:
            self.down()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self.down()

    def addr(self, i: int) -> str:
        """Host i's address."""
        return f"{self.subnet}.{i}"

    def link(self, i: int, state: str) -> None:
        """Take host i's link ``down`` or bring it ``up``."""
        _ip("-n", self.names[i - 1], "link", "set", f"{self.tag}a{i}", state)

    def cmd(self, i: int, *argv: str) -> list[str]:
        """``argv`` run on host i."""
        return ["ip", "netns", "exec", self.names[i - 1], *argv]

    def down(self) -> None:
        """Delete every namespace made (their veth ends go with them)."""
        for ns in reversed(self.made):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=10)
        self.made.clear()
