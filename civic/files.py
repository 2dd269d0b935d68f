"""Reading the user's TOML and JSON documents: every failure is one CivicError line."""
from __future__ import annotations

import json
import tomllib
from pathlib import Path

from civic.errors import CivicError


def _read_text(path: str | Path, what: str) -> str:
    try:
        return Path(path).read_text()
    except OSError as exc:
        raise CivicError(f"cannot read {what}{path}: {exc.strerror}") from exc
    except UnicodeDecodeError as exc:
        raise CivicError(f"{path}: not a text file ({exc.reason})") from exc


def read_toml(path: str | Path, what: str = "") -> dict:
    """The parsed TOML document; `what` names the kind of file in errors ('model ')."""
    try:
        return tomllib.loads(_read_text(path, what))
    except tomllib.TOMLDecodeError as exc:
        raise CivicError(f"{path}: invalid TOML: {exc}") from exc


def read_json(path: str | Path, what: str = ""):
    """The parsed JSON document; `what` names the kind of file in errors."""
    try:
        return json.loads(_read_text(path, what))
    except json.JSONDecodeError as exc:
        raise CivicError(f"{path}: invalid JSON: {exc}") from exc
