"""civic watch: follow a running CIVIC switch's verdicts live (digests, counters, metrics)."""
from __future__ import annotations

import sys
import time
from contextlib import contextmanager

from civic.errors import CivicError

RECONNECT_S = 1.0
HIGHLIGHT_S = 3.0


def register(sub) -> None:
    p = sub.add_parser("watch", help="follow a switch's verdict changes live: table, JSON lines, Prometheus",
                       description="Join a CIVIC switch as a P4Runtime controller (election id 1: civic "
                                   "configure, id 10, takes over for its writes), enable and acknowledge its "
                                   "verdict-change digests, read its verdict counters.")
    p.add_argument("--switch", required=True, metavar="HOST:PORT", help="P4Runtime gRPC address")
    p.add_argument("--entries", metavar="ENTRIES.json", help="names the monitors (default m0, m1, ...)")
    p.add_argument("--events", metavar="FILE", help="append every verdict change as a JSON line")
    p.add_argument("--metrics-port", type=int, metavar="N", help="serve Prometheus metrics on port N")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds (default: until Ctrl-C)")
    p.add_argument("--plot", metavar="PNG", help="at the end, the plants' class timeline")
    add_opcua_args(p)
    p.add_argument("--device-id", type=int, default=0, metavar="N")
    p.add_argument("--election-id", type=int, default=1, metavar="N", help="election id (default 1)")
    p.add_argument("--timeout", type=float, default=5.0, metavar="S", help="connect timeout in seconds")
    p.set_defaults(func=run)


def table(watcher, now: float, title: str = "civic watch"):
    from rich.table import Table

    from civic.watch import class_name

    st = watcher.state
    age = f"{now - st.last_digest:.1f} s ago" if st.last_digest else "none yet"
    t = Table(title=f"{title} {watcher.address}: {st.events_total} changes, last digest {age}",
              title_justify="left")
    for col in ("plant", "monitor", "class", "since", "normal", "warning", "error"):
        t.add_column(col, justify="right" if col in ("since", "normal", "warning", "error") else "left")
    colors = {1: "green", 2: "yellow", 3: "red"}
    for (plant, monitor), c in sorted(st.cells.items()):
        name = class_name(c.cls)
        if c.cls:
            name = f"[{colors[c.cls]}]{name}[/]"
        since = f"{now - c.since:.0f} s" if c.since else ""
        style = "bold reverse" if now - c.changed_at < HIGHLIGHT_S else None
        t.add_row(plant, monitor, name, since, *(str(c.counts.get(k, 0)) for k in (1, 2, 3)), style=style)
    return t


def run(args) -> int:
    names, prefix = None, None
    if args.entries:
        from civic.entries import load_entries
        entries = load_entries(args.entries)
        names, prefix = [m.name for m in entries.monitors], entries.plant_prefix
    with opcua_session(args) as opcua:
        from civic.watch import Watcher

        events_file = open_events(args.events)
        watcher = Watcher(args.switch, names, args.device_id, args.election_id, args.timeout, events_file, prefix,
                          printer())
        watcher.connect()                  # unreachable / not CIVIC: one line, exit 2
        follow(watcher, args, events_file, f"watching {args.switch}", "civic watch",
               lambda wait: poll(watcher, wait), opcua)
    st = watcher.state
    print(f"stopped: {st.events_total} verdict changes from {len({p for p, _ in st.cells})} plants",
          file=sys.stderr)
    plot(args, st)
    return 0


def poll(watcher, wait: float) -> None:
    """One poll; a lost connection is reopened (with a message), never a traceback."""
    try:
        if watcher.conn is None:
            watcher.connect()
            print(f"civic watch: reconnected to {watcher.address}", file=sys.stderr, flush=True)
        watcher.poll(wait)
    except CivicError as exc:
        watcher.close()
        print(f"civic watch: {exc}; retrying in {RECONNECT_S:g} s", file=sys.stderr, flush=True)
        time.sleep(RECONNECT_S)


# -- what civic watch and civic monitor share: a source with a WatchState, polled until the end
def add_opcua_args(p) -> None:
    p.add_argument("--opcua", metavar="ENDPOINT", help="serve the verdicts over OPC UA, e.g. "
                   "opc.tcp://0.0.0.0:4840/civic (read-only; anonymous unless --opcua-cert/--opcua-key)")
    p.add_argument("--opcua-cert", metavar="CERT", help="server certificate (PEM/DER): the endpoint becomes "
                   "Basic256Sha256 SignAndEncrypt only")
    p.add_argument("--opcua-key", metavar="KEY", help="the certificate's private key (PEM/DER)")
    p.add_argument("--opcua-users", metavar="FILE", help="only these users (NAME:HASH lines, civic opcua-user)")
    p.add_argument("--opcua-trust", metavar="DIR", help="only clients whose application certificate (or its "
                   "issuer) is in DIR")


@contextmanager
def opcua_session(args):
    """Check the session's options; the OPC UA server of --opcua, started first (it builds its address
    space while the session starts) and closed at the end; None without --opcua."""
    server = check_session(args)
    if server is None:
        yield None
        return
    server.start()
    try:
        yield server
    finally:
        server.close()


def check_session(args):
    """Check the session's options; the OPC UA server of --opcua (not started), or None."""
    if args.duration is not None and args.duration <= 0:
        raise CivicError("--duration must be > 0")
    if args.metrics_port is not None and not 0 < args.metrics_port < 65536:
        raise CivicError("--metrics-port must be 1..65535")
    if args.opcua is None:
        if args.opcua_cert or args.opcua_key or args.opcua_users or args.opcua_trust:
            raise CivicError("--opcua-cert, --opcua-key, --opcua-users and --opcua-trust need --opcua ENDPOINT")
        return None
    from civic.opcua import OpcUaServer
    return OpcUaServer(args.opcua, args.opcua_cert, args.opcua_key, args.opcua_users, args.opcua_trust)


def open_events(path: str | None):
    try:
        return open(path, "a") if path else None
    except OSError as exc:
        raise CivicError(f"cannot open {path}: {exc.strerror}") from None


def printer():
    """Without a terminal (no live table), each change is printed as a line."""
    if sys.stdout.isatty():
        return None
    return lambda ev: print(f"{ev['plant']} {ev['monitor']}: {ev['from'] or '-'} -> {ev['to']} (seq {ev['seq']})",
                            flush=True)


def follow(source, args, events_file, started: str, title: str, poll, opcua=None) -> None:
    """Serve the metrics and OPC UA, then poll(wait) until --duration is up or Ctrl-C, under the live
    table on a terminal; the source, the servers and the events file are closed whatever happens."""
    stop_metrics = None
    try:
        if opcua is not None:
            opcua.serve(source.state)
            source.on_event = both(source.on_event, opcua.publish)
        if args.metrics_port is not None:
            from civic.metrics import serve
            stop_metrics = serve(source.state, args.metrics_port)
        print(f"{started} ({', '.join(source.state.monitors)})"
              + (f", metrics on :{args.metrics_port}" if args.metrics_port else "")
              + (f", OPC UA on {args.opcua}" if opcua is not None else ""), file=sys.stderr, flush=True)
        end = None if args.duration is None else time.monotonic() + args.duration
        if sys.stdout.isatty():
            from rich.live import Live

            from civic.report import console
            with Live(table(source, time.time(), title), console=console, refresh_per_second=4) as view:
                loop(end, poll, lambda: view.update(table(source, time.time(), title)))
        else:
            loop(end, poll, None)
    except KeyboardInterrupt:
        pass
    finally:
        source.close()
        if stop_metrics is not None:
            stop_metrics()
        if events_file is not None:
            events_file.close()


def both(first, second):
    """One on_event hook calling two (first may be None)."""
    if first is None:
        return second

    def hook(ev):
        first(ev)
        second(ev)
    return hook


def loop(end, poll, redraw) -> None:
    """poll(wait) until `end` (None: forever), redrawing after each."""
    while end is None or time.monotonic() < end:
        poll(0.25 if end is None else max(0.0, min(0.25, end - time.monotonic())))
        if redraw is not None:
            redraw()


def plot(args, state) -> None:
    if args.plot:
        from civic.timeline import plot_timeline
        plot_timeline(state.events, args.plot, end_t=time.time())
