"""civic watch: follow a running CIVIC switch's verdicts live (digests, counters, metrics)."""
from __future__ import annotations

import sys
import time

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
    from civic.watch import Watcher

    if args.duration is not None and args.duration <= 0:
        raise CivicError("--duration must be > 0")
    if args.metrics_port is not None and not 0 < args.metrics_port < 65536:
        raise CivicError("--metrics-port must be 1..65535")
    names, prefix = None, None
    if args.entries:
        from civic.entries import load_entries
        entries = load_entries(args.entries)
        names, prefix = [m.name for m in entries.monitors], entries.plant_prefix
    try:
        events_file = open(args.events, "a") if args.events else None
    except OSError as exc:
        raise CivicError(f"cannot open {args.events}: {exc.strerror}") from None
    live = sys.stdout.isatty()
    on_event = None if live else (lambda ev: print(f"{ev['plant']} {ev['monitor']}: {ev['from'] or '-'} -> "
                                                   f"{ev['to']} (seq {ev['seq']})", flush=True))
    watcher = Watcher(args.switch, names, args.device_id, args.election_id, args.timeout, events_file, prefix,
                      on_event)
    watcher.connect()                  # unreachable / not CIVIC: one line, exit 2
    stop_metrics = None
    end = None if args.duration is None else time.monotonic() + args.duration
    try:
        if args.metrics_port is not None:
            from civic.metrics import serve
            stop_metrics = serve(watcher.state, args.metrics_port)
        print(f"watching {args.switch} ({', '.join(watcher.state.monitors)})"
              + (f", metrics on :{args.metrics_port}" if args.metrics_port else ""), file=sys.stderr, flush=True)
        if live:
            from rich.live import Live

            from civic.report import console
            with Live(table(watcher, time.time()), console=console, refresh_per_second=4) as view:
                loop(watcher, end, lambda: view.update(table(watcher, time.time())))
        else:
            loop(watcher, end, None)
    except KeyboardInterrupt:
        pass
    finally:
        watcher.close()
        if stop_metrics is not None:
            stop_metrics()
        if events_file is not None:
            events_file.close()
    st = watcher.state
    print(f"stopped: {st.events_total} verdict changes from {len({p for p, _ in st.cells})} plants",
          file=sys.stderr)
    if args.plot:
        from civic.timeline import plot_timeline
        plot_timeline(st.events, args.plot, end_t=time.time())
    return 0


def loop(watcher, end, redraw) -> None:
    """Poll until `end`; a lost connection is reopened (with a message), never a traceback."""
    while end is None or time.monotonic() < end:
        wait = 0.25 if end is None else max(0.0, min(0.25, end - time.monotonic()))
        try:
            if watcher.conn is None:
                watcher.connect()
                print(f"civic watch: reconnected to {watcher.address}", file=sys.stderr, flush=True)
            watcher.poll(wait)
        except CivicError as exc:
            watcher.close()
            print(f"civic watch: {exc}; retrying in {RECONNECT_S:g} s", file=sys.stderr, flush=True)
            time.sleep(RECONNECT_S)
        if redraw is not None:
            redraw()
