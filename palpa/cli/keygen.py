"""``palpa keygen DIR NAME``: a CURVE key pair (NAME.key public, NAME.key_secret secret) for bus encryption."""

from __future__ import annotations

import argparse
from pathlib import Path

from palpa.net.keys import create_key_pair


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("keygen", help="create a CURVE key pair for an encrypted tcp bus")
    p.add_argument("dir", type=Path)
    p.add_argument("name")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    public, secret = create_key_pair(args.dir, args.name)
    print(f"public {public}\nsecret {secret} (mode 0600: only you can read it)")
    return 0
