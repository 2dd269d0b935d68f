"""civic monitor: the software switch on live frames from an interface (a mirror port or tap)."""
from __future__ import annotations

import sys
import time

from civic.commands.watch import add_opcua_args


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
    p.add_argument("--write", metavar="OUT.pcap",
                   help="write every captured frame, verdicts written in (pcapng if OUT ends in .pcapng)")
    p.add_argument("--plot", metavar="PNG", help="at the end, the plants' class timeline")
    add_opcua_args(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from civic.commands.watch import follow, opcua_session, open_events, plot, printer
    from civic.entries import load_entries

    entries = load_entries(args.entries)
    with opcua_session(args) as opcua:
        from civic.monitor import Monitor         # numba: imported while the OPC UA server builds

        events_file = open_events(args.events)
        monitor = Monitor(args.iface, entries, events_file, args.write, printer())   # bad iface: one line, exit 2
        start = time.monotonic()
        follow(monitor, args, events_file, f"monitoring {args.iface}", "civic monitor", monitor.poll, opcua)
    st = monitor.state
    print(f"stopped: {monitor.frames} frames ({monitor.plant_messages} plant messages) in "
          f"{time.monotonic() - start:.1f} s, {monitor.dropped} dropped by the kernel; {st.events_total} verdict "
          f"changes from {len({p for p, _ in st.cells})} plants", file=sys.stderr)
    plot(args, st)
    return 0
