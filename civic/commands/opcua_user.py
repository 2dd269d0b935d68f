"""civic opcua-user: a line of the --opcua-users file (a user name and its salted password hash)."""
from __future__ import annotations

import getpass
import sys

from civic.errors import CivicError


def register(sub) -> None:
    p = sub.add_parser("opcua-user", help="print a --opcua-users line for a user (asks for the password)",
                       description="Prints NAME:pbkdf2_sha256$ROUNDS$SALT$HASH; append it to the file given to "
                                   "--opcua-users. The password is read from the terminal, or from stdin's first "
                                   "line when stdin is not a terminal.")
    p.add_argument("name", metavar="NAME")
    p.set_defaults(func=run)


def run(args) -> int:
    from civic.opcua import hash_password

    if not args.name or ":" in args.name or args.name != args.name.strip():
        raise CivicError(f"user name {args.name!r}: no ':' and no surrounding spaces")
    if sys.stdin.isatty():
        password = getpass.getpass(f"password for {args.name}: ")
        if getpass.getpass("again: ") != password:
            raise CivicError("the passwords differ")
    else:
        password = sys.stdin.readline().rstrip("\n")
    if not password:
        raise CivicError("empty password")
    print(f"{args.name}:{hash_password(password)}")
    return 0
