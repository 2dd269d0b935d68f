"""`civic configure`: install table entries on a switch over P4Runtime (or show what it holds)."""
from __future__ import annotations

import argparse

from civic.errors import CivicError

CONFIGURE_ELECTION_ID = 10   # civic watch joins with 1


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "configure", help="install table entries on a switch over P4Runtime",
        description="Converge a P4Runtime switch to an entries file written by `civic train`: "
                    "insert, modify and delete exactly what differs, then read back and verify. "
                    "With --read, show the installed entries and per-plant register state instead.")
    p.add_argument("--switch", required=True, metavar="HOST:PORT", help="P4Runtime gRPC address")
    p.add_argument("--entries", metavar="ENTRIES.json", help="table entries (required unless --read)")
    p.add_argument("--pipeline", metavar="DIR",
                   help="install the pipeline from DIR (civic.json + civic.p4info.txtpb) unless the "
                        "switch already runs it")
    p.add_argument("--device-id", type=int, default=0, metavar="N", help="P4Runtime device id (default 0)")
    p.add_argument("--election-id", type=int, default=CONFIGURE_ELECTION_ID, metavar="N",
                   help=f"election id (default {CONFIGURE_ELECTION_ID}: above a running `civic watch`, which "
                        "stays connected and is primary again when configure leaves)")
    p.add_argument("--timeout", type=float, default=5.0, metavar="S", help="connect timeout in seconds")
    p.add_argument("--padded-bytes", action="store_true",
                   help="send full-width byte strings (P4Runtime servers built before PI accepted the "
                        "canonical form, e.g. older simple_switch_grpc)")
    p.add_argument("--read", action="store_true", help="print installed entries and register state")
    p.add_argument("--plant", metavar="IP", help="with --read: only this plant's state slot")
    p.set_defaults(func=run)


def _check_address(text: str) -> str:
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise CivicError(f"--switch {text!r}: expected HOST:PORT")
    return text


def run(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    from civic.switch.converge import configure

    address = _check_address(args.switch)
    if args.election_id < 0 or args.election_id >= 1 << 128:
        raise CivicError("--election-id must be 0..2^128-1")
    console = Console()
    if args.plant and not args.read:
        raise CivicError("--plant only goes with --read")
    if args.read:
        return _read(args, address, console)
    if not args.entries:
        raise CivicError("--entries is required (unless --read)")
    result = configure(address, args.entries, args.pipeline, args.device_id, args.election_id, args.timeout,
                            args.padded_bytes)
    table = Table(title=f"civic configure {address} (device {args.device_id})")
    for col in ("added", "modified", "deleted", "unchanged"):
        table.add_column(col, justify="right")
    table.add_row(str(result.added), str(result.modified), str(result.deleted), str(result.unchanged))
    console.print(table)
    if result.pipeline_pushed:
        console.print(f"pipeline installed from {args.pipeline} (all register state zeroed)")
    if result.cleared:
        console.print("registers zeroed for reconfigured monitor slot(s) "
                      + ", ".join(str(k) for k in result.cleared))
    console.print("switch state verified by read-back" if result.writes else
                  "already up to date: nothing written")
    return 0


def _read(args, address: str, console) -> int:
    from rich.table import Table

    from civic.entries import load_entries
    from civic.switch.connection import SwitchConnection, Unsupported
    from civic.switch.converge import read_state
    from civic.switch.pipeline import ensure_pipeline
    from civic.switch.registers import monitor_config, plant_slot, read_plant_state
    from civic.switch.schema import CONTROL

    prefix = load_entries(args.entries).plant_prefix if args.entries else None
    slots = [plant_slot(args.plant, prefix)] if args.plant else None
    with SwitchConnection(address, args.device_id, args.election_id, args.timeout, arbitrate=False) as conn:
        schema, _ = ensure_pipeline(conn, None)
        entries, defaults = read_state(conn, schema)
        t = Table(title=f"entries on {address}")
        t.add_column("table")
        t.add_column("entry")
        for te in sorted(defaults + entries, key=lambda e: (e.table_id, not e.is_default_action, -e.priority)):
            name, _, rest = schema.describe(te).partition(" ")
            t.add_row(name.removeprefix(CONTROL + "."), rest)
        console.print(t)
        config = monitor_config(schema, defaults)
        try:
            states = read_plant_state(conn, schema, config, slots)
        except Unsupported as exc:
            if slots:
                raise CivicError(f"cannot read plant state: {exc} (BMv2: p4lang/PI#376; "
                                 "use simple_switch_CLI register_read)") from None
            console.print(f"plant state not shown: {exc}")
            return 0
    r = Table(title="plant state" + (f" ({args.plant}, slot {slots[0]})" if slots else ""))
    for col in ("slot", "last_seq", "monitor", "run", "ptr", "s0", "s1", "ring (oldest first)"):
        r.add_column(col)
    for st in states:
        first = True
        for k, m in enumerate(st.monitors):
            if m is None:
                continue
            ring = " ".join(str(v) for v in m["ring"])
            r.add_row(str(st.slot) if first else "", str(st.last_seq) if first else "", f"mon{k}",
                      str(m["run"]), str(m["ptr"]), str(m["s0"]), str(m["s1"]), ring)
            first = False
        if first:
            r.add_row(str(st.slot), str(st.last_seq), "-", "", "", "", "", "")
    console.print(r if states else "no plant state (no plant message seen)")
    return 0
