"""CURVE key files: made private (0600), loaded only when private (as ssh does), and the bus's set of authorised
client keys, which logs every refusal and can be reloaded while the bus runs (``palpa bus`` on SIGHUP)."""

from __future__ import annotations

import logging
import os
import stat
import threading
from pathlib import Path

import zmq.auth

from palpa import env as palpa_env
from palpa.errors import BusError, PalpaError
from palpa.lograte import LogThrottle

__all__ = ["ClientKeys", "create_key_pair", "curve_client_options", "load_secret_key"]

log = logging.getLogger("palpa.net.bus.auth")


def create_key_pair(directory: Path, name: str, *, force: bool = False) -> tuple[Path, Path]:
    """``NAME.key`` (public, 0644) and ``NAME.key_secret`` (0600, never readable by anyone else) in ``directory``.
    Refuses (:class:`PalpaError`) when either exists, unless ``force``: a replaced pair locks out whoever holds the
    old public key (every client of a bus, or the bus its clients trust)."""
    existing = [p for p in (directory / f"{name}.key", directory / f"{name}.key_secret") if p.exists()]
    if existing and not force:
        raise PalpaError(f"{', '.join(map(str, existing))} already exist{'s' if len(existing) == 1 else ''}: "
                         "a new pair would lock out whoever holds the old public key; nothing was written "
                         "(--force replaces it)")
    for path in existing:
        path.unlink()  # written afresh under the umask below, never through an old file's mode
    directory.mkdir(parents=True, exist_ok=True)
    old = os.umask(0o077)  # the secret file is private from its first byte
    try:
        public, secret = zmq.auth.create_certificates(str(directory), name)
    finally:
        os.umask(old)
    os.chmod(public, 0o644)
    os.chmod(secret, 0o600)
    return Path(public), Path(secret)


def load_secret_key(path: str | os.PathLike[str]) -> tuple[bytes, bytes]:
    """(public, secret) from a ``.key_secret`` file; refuses a file group or others may read."""
    try:
        mode = os.stat(path).st_mode
    except OSError as exc:
        raise BusError(f"cannot read the secret key file {path}: {exc.strerror or exc}") from None
    if mode & 0o077:
        raise BusError(f"{path}: secret key file is accessible by others (mode {stat.S_IMODE(mode):04o}); "
                       f"run: chmod 600 {path}")
    public, secret = zmq.auth.load_certificate(str(path))
    if secret is None:
        raise BusError(f"{path}: not a CURVE secret key file")
    return public, secret


class ClientKeys:
    """The public keys a CURVE bus lets in (``*.key`` files of one folder). Used as pyzmq's credentials provider
    (``callback``, called by the ZAP thread for every handshake); :meth:`reload` rereads the folder."""

    def __init__(self, directory: Path) -> None:
        self.directory = directory
        self._keys: frozenset[bytes] = frozenset()
        self._throttle = LogThrottle(log)
        self._lock = threading.Lock()
        self.refused = 0
        """Handshakes refused so far."""
        self.generation = 0
        """How many times the folder was read (a change tells the bus to republish the keys)."""
        self.reload()

    def reload(self) -> int:
        """Reread the folder; returns how many keys are now authorised."""
        if not self.directory.is_dir():
            raise BusError(f"--curve-clients {self.directory}: no such folder")
        keys = frozenset(k if isinstance(k, bytes) else str(k).encode()
                         for k in zmq.auth.load_certificates(str(self.directory)))
        self._keys = keys
        self.generation += 1
        log.info("CURVE: %d authorised client key(s) from %s", len(keys), self.directory)
        return len(keys)

    def listing(self) -> bytes:
        """The authorised keys, Z85, one a line (what the bus publishes for direct CURVE publishers)."""
        return b"\n".join(sorted(self._keys))

    def callback(self, domain: str, z85_key: bytes) -> bool:
        """pyzmq's hook: True lets the client in; a refusal is counted and logged, one line per
        :data:`palpa.lograte.LOG_INTERVAL_S` whatever the keys (each line says how many it stands for)."""
        if z85_key in self._keys:
            return True
        with self._lock:
            self.refused += 1
            self._throttle.event("refused", logging.WARNING, "CURVE: refused a client with unknown public key %s "
                                 "(%d refusals so far; add its .key file to %s and send the bus SIGHUP to let it in)",
                                 z85_key.decode(errors="replace"), self.refused, self.directory)
        return False


def curve_client_options() -> dict[str, bytes] | None:
    """CURVE client keys from the environment, or None when the bus is not encrypted.

    ``PALPA_BUS_SERVER_KEY``: the server's public key (Z85 text, or a path to its ``.key`` file);
    ``PALPA_CURVE_SECRET``: the path to this client's ``.key_secret`` file (its public key must be authorised
    on the bus).
    """
    server = palpa_env.get(palpa_env.BUS_SERVER_KEY) or None
    if not server:
        return None
    secret_file = palpa_env.get(palpa_env.CURVE_SECRET) or None
    if not secret_file:
        raise BusError("PALPA_BUS_SERVER_KEY is set but PALPA_CURVE_SECRET (client secret key file) is not")
    if Path(server).is_file():
        server_public, _ = zmq.auth.load_certificate(server)
    else:
        server_public = server.encode()
    public, secret = load_secret_key(secret_file)
    return {"server": server_public, "public": public, "secret": secret}
