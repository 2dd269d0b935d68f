"""Verdict-change events: what the switch's digests say, as JSON lines.

One event per (plant, monitor) whose verdict changes, in message order:
{"t": capture time in s, "plant": "10.0.0.1", "monitor": "drain_t3",
 "from": "normal"|"warning"|"error"|null, "to": "...", "seq": n, "slope": raw, "level": mL}
`from` is null for a plant's first verdict from that monitor.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from civic.errors import CivicError
from civic.pipeline.notify import Change
from civic.pipeline.slope import to_int32
from civic.wire import VERDICT_NAMES, int_to_ip

KEYS = ("t", "plant", "monitor", "from", "to", "seq", "slope", "level")


def class_name(code: int) -> str | None:
    return VERDICT_NAMES[code] if code else None


def event(change: Change, t: float, monitors: list[str]) -> dict:
    name = monitors[change.monitor] if change.monitor < len(monitors) else f"m{change.monitor}"
    return {"t": round(float(t), 6), "plant": int_to_ip(change.plant), "monitor": name,
            "from": class_name(change.prev), "to": class_name(change.cls), "seq": int(change.seq),
            "slope": int(to_int32(change.slope)), "level": int(change.level)}


def digest_changes(member: dict[str, int], monitors: int) -> list[Change]:
    """One verdict_change_t digest (docs/pipeline.md section 7) -> its changes, monitors in order."""
    out = []
    for m in range(monitors):
        if member["changed"] >> m & 1:
            out.append(Change(-1, member["plant"], m, member["prev"] >> 2 * m & 3, member["cls"] >> 2 * m & 3,
                              member["seq"], int(to_int32(member[f"slope{m}"])), member[f"level{m}"]))
    return out


def place(digests: list[list[Change]], messages: np.ndarray) -> list[Change]:
    """Give each digest's changes the index of their message: the switch processes messages in
    order, so it is the first message from that plant with that seq at or after the previous
    digest's message. Returns the changes in order."""
    from collections import defaultdict

    where = defaultdict(list)
    for i in np.flatnonzero(messages["plant"]):
        where[(int(messages["src"][i]), int(messages["seq"][i]))].append(int(i))
    cursor = 0
    out = []
    for changes in digests:
        if not changes:
            continue
        key = (changes[0].plant, changes[0].seq)
        later = [i for i in where.get(key, []) if i >= cursor]
        if not later:
            raise CivicError(f"a digest names plant {int_to_ip(key[0])} seq {key[1]}, "
                             "which the capture does not hold at that point")
        cursor = later[0]
        for c in changes:
            c.index = cursor
        out.extend(changes)
    return out


def write_events(path: str | Path, events: list[dict]) -> None:
    try:
        with open(path, "w") as fh:
            for e in events:
                fh.write(json.dumps(e) + "\n")
    except OSError as exc:
        raise CivicError(f"cannot write {path}: {exc.strerror}") from None


def read_events(path: str | Path) -> list[dict]:
    try:
        lines = Path(path).read_text().splitlines()
    except OSError as exc:
        raise CivicError(f"cannot read {path}: {exc.strerror}") from None
    return [json.loads(ln) for ln in lines if ln.strip()]
