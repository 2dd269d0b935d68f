"""civic monitor: the software switch on live frames from an interface (a mirror port or tap)."""
from __future__ import annotations

import sys
import time

from civic.errors import CivicError


def register(sub) -> None:
    p = sub.add_parser("monitor", help="verdicts from live frames on an interface (the software switch)",
                       description="Capture the plant's messages from an interface (a switch's mirror port or a "
                                   "tap; needs root or CAP_NET_RAW) and run them through the bit-exact software "
                                   "switch: the same verdicts and changes as civic replay --target model, shown "
                                   "as civic watch shows a switch's.")
    p.add_argument("--iface", required=True, metavar="IFACE", help="interface to capture from")
    p.add_argument("--entries", required=True, metavar="ENTRIES.json")
    p.add_argument("--events", metavar="FILE", help="append every verdict change as a JSON line")
    p.add_argument("--metrics-port", type=int, metavar="N", help="serve Prometheus metrics on port N")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds (default: until Ctrl-C)")
    p.add_argument("--write", metavar="OUT.pcap", help="write every captured frame, verdicts written in")
    p.add_argument("--plot", metavar="PNG", help="at the end, the plants' class timeline")
    p.set_defaults(func=run)


def run(args) -> int:
    from civic.commands.watch import table
    from civic.entries import load_entries
    from civic.monitor import Monitor

    if args.duration is not None and args.duration <= 0:
        raise CivicError("--duration must be > 0")
    if args.metrics_port is not None and not 0 < args.metrics_port < 65536:
        raise CivicError("--metrics-port must be 1..65535")
    entries = load_entries(args.entries)
    try:
        events_file = open(args.events, "a") if args.events else None
    except OSError as exc:
        raise CivicError(f"cannot open {args.events}: {exc.strerror}") from None
    live = sys.stdout.isatty()
    on_event = None if live else (lambda ev: print(f"{ev['plant']} {ev['monitor']}: {ev['from'] or '-'} -> "
                                                   f"{ev['to']} (seq {ev['seq']})", flush=True))
    monitor = Monitor(args.iface, entries, events_file, args.write, on_event)   # bad iface: one line, exit 2
    stop_metrics = None
    start = time.monotonic()
    end = None if args.duration is None else start + args.duration
    try:
        if args.metrics_port is not None:
            from civic.metrics import serve
            stop_metrics = serve(monitor.state, args.metrics_port)
        print(f"monitoring {args.iface} ({', '.join(monitor.names)})"
              + (f", metrics on :{args.metrics_port}" if args.metrics_port else ""), file=sys.stderr, flush=True)
        if live:
            from rich.live import Live

            from civic.report import console
            with Live(table(monitor, time.time(), "civic monitor"), console=console, refresh_per_second=4) as view:
                loop(monitor, end, lambda: view.update(table(monitor, time.time(), "civic monitor")))
        else:
            loop(monitor, end, None)
    except KeyboardInterrupt:
        pass
    finally:
        monitor.close()
        if stop_metrics is not None:
            stop_metrics()
        if events_file is not None:
            events_file.close()
    st = monitor.state
    took = time.monotonic() - start
    print(f"stopped: {monitor.frames} frames ({monitor.plant_messages} plant messages) in {took:.1f} s, "
          f"{monitor.dropped} dropped by the kernel; {st.events_total} verdict changes from "
          f"{len({p for p, _ in st.cells})} plants", file=sys.stderr)
    if args.plot:
        from civic.timeline import plot_timeline
        plot_timeline(st.events, args.plot, end_t=time.time())
    return 0


def loop(monitor, end, redraw) -> None:
    """Poll until `end` (or forever)."""
    while end is None or time.monotonic() < end:
        wait = 0.25 if end is None else max(0.0, min(0.25, end - time.monotonic()))
        monitor.poll(wait)
        if redraw is not None:
            redraw()
