"""`eca keys new NAME` / `eca keys list`: the CURVE key pairs of a bus across hosts (docs/protocol.md §15).

`new` writes `NAME.key` (the public key, to hand to the other side) and `NAME.key_secret` (the pair, mode
0600, never to leave its host) with zmq.auth's certificate format; `list` shows each pair's public key in
Z85 and whether its secret file is there and private. Exit codes: 0 done, 1 a key file or folder is wrong,
2 bad arguments.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import tempfile
from pathlib import Path

from eca.protocol.curve import PUBLIC_SUFFIX, SECRET_SUFFIX, CurveKeyError, check_secret_mode, load_key_file

_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,63}")


def default_dir() -> Path:
    base = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(base) / "eca" / "keys"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("keys", help="make and list CURVE key pairs for a bus across hosts",
                       description="CURVE key pairs for the bus across hosts (docs/protocol.md §15). The broker's "
                                   "host holds the server pair; every host holds a pair of its own, and the "
                                   "broker lets in the public keys in its curve_allowed_dir.")
    actions = p.add_subparsers(dest="keys_action", metavar="ACTION", required=True)
    new = actions.add_parser("new", help="create a key pair NAME.key (public) and NAME.key_secret (0600)")
    new.add_argument("name", help="1-64 letters, digits, '_' or '-' (the files' name)")
    new.add_argument("--dir", type=Path, default=None, help=f"the folder (default {default_dir()})")
    new.add_argument("--force", action="store_true", help="replace a pair of that name")
    new.set_defaults(func=run_new)
    show = actions.add_parser("list", help="list the key pairs and public keys in a folder")
    show.add_argument("--dir", type=Path, default=None, help=f"the folder (default {default_dir()})")
    show.set_defaults(func=run_list)


def new_pair(directory: Path, name: str, force: bool = False) -> tuple[Path, Path, str]:
    """Create NAME's pair in `directory`: (public file, secret file, public key in Z85)."""
    import zmq.auth

    if not _NAME.fullmatch(name):
        raise CurveKeyError(f"key name {name!r}: use 1-64 letters, digits, '_' or '-', starting with a letter "
                            "or digit")
    directory.mkdir(mode=0o700, parents=True, exist_ok=True)
    public, secret = directory / f"{name}{PUBLIC_SUFFIX}", directory / f"{name}{SECRET_SUFFIX}"
    if not force and (public.exists() or secret.exists()):
        raise CurveKeyError(f"{secret}: a key pair named {name!r} exists; give --force to replace it")
    # Written in a private (0700) folder first and moved into place: the secret file is never, even for a
    # moment, readable by others (create_certificates writes with the process's umask).
    with tempfile.TemporaryDirectory(dir=directory, prefix=".new-") as tmp:
        made_public, made_secret = zmq.auth.create_certificates(tmp, name)
        os.chmod(made_secret, 0o600)
        os.chmod(made_public, 0o644)
        os.replace(made_secret, secret)
        os.replace(made_public, public)
    key, _ = load_key_file(secret, need_secret=True)
    return public, secret, key.decode()


def list_pairs(directory: Path) -> list[str]:
    """One line per key in `directory`: name, public key (Z85), what is there; a bad file is named, not fatal."""
    if not directory.is_dir():
        raise CurveKeyError(f"{directory}: no such folder")
    lines = []
    names = sorted({p.name.removesuffix(SECRET_SUFFIX).removesuffix(PUBLIC_SUFFIX)
                    for p in directory.iterdir() if p.name.endswith((PUBLIC_SUFFIX, SECRET_SUFFIX))})
    for name in names:
        public, secret = directory / f"{name}{PUBLIC_SUFFIX}", directory / f"{name}{SECRET_SUFFIX}"
        try:
            key, _ = load_key_file(public if public.exists() else secret, need_secret=False)
            if secret.exists():
                check_secret_mode(secret)
                secret_key, _ = load_key_file(secret, need_secret=True)
                if secret_key != key:
                    raise CurveKeyError(f"{secret}: its public key differs from {public.name}'s")
                what = "pair (public + secret)"
            else:
                what = "public only"
            lines.append(f"{name:<24} {key.decode()}  {what}")
        except CurveKeyError as exc:
            lines.append(f"{name:<24} {'-' * 40}  BAD: {exc}")
    return lines


def run_new(args: argparse.Namespace) -> int:
    directory = args.dir or default_dir()
    try:
        public, secret, key = new_pair(directory, args.name, args.force)
    except (CurveKeyError, OSError) as exc:
        print(f"eca keys new: {exc}", file=sys.stderr)
        return 1
    print(f"{args.name}: public key {key}\n  public  {public}  (give it to the other side)\n"
          f"  secret  {secret}  (mode 0600; never leaves this host)")
    return 0


def run_list(args: argparse.Namespace) -> int:
    directory = args.dir or default_dir()
    try:
        lines = list_pairs(directory)
    except (CurveKeyError, OSError) as exc:
        print(f"eca keys list: {exc}", file=sys.stderr)
        return 1
    print(f"# {directory}: {len(lines)} key(s)")
    for line in lines:
        print(line)
    return 1 if any(" BAD: " in line for line in lines) else 0
