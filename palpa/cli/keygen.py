"""``palpa keygen DIR NAME [--force]``: a CURVE key pair (NAME.key public, NAME.key_secret secret) for bus encryption;
an existing pair is replaced only with ``--force``."""

from __future__ import annotations

import argparse
from pathlib import Path

from palpa.net.keys import create_key_pair


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("keygen", help="create a CURVE key pair for an encrypted tcp bus")
    p.add_argument("dir", type=Path)
    p.add_argument("name")
    p.add_argument("--force", action="store_true", help="replace an existing pair of that name (its holders are "
                                                        "locked out)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    public, secret = create_key_pair(args.dir, args.name, force=args.force)
    print(f"public {public}\nsecret {secret} (mode 0600: only you can read it)")
    return 0
