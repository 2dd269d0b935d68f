"""civic replay: recordings through the switch (software model or BMv2), verdicts written in."""
from __future__ import annotations

from pathlib import Path

from civic.errors import CivicError


def register(sub) -> None:
    p = sub.add_parser("replay", help="replay recordings through the switch and write verdicts")
    p.add_argument("inputs", nargs="+", metavar="IN.pcap")
    p.add_argument("-o", "--output", required=True, metavar="OUT", help="a file for one input, a folder for several")
    p.add_argument("--entries", required=True, metavar="ENTRIES.json")
    p.add_argument("--target", choices=("model", "bmv2"), default="model")
    p.add_argument("--pipeline", metavar="DIR", default="build/v1model",
                   help="bmv2: folder with civic.json and civic.p4info.txtpb")
    p.add_argument("--events", metavar="EVENTS.jsonl",
                   help="write every verdict change as a JSON line (BMv2: from the switch's digests)")
    p.add_argument("--timeline", metavar="PNG", help="the plants' class timeline from the verdict changes")
    p.set_defaults(func=run)


def output_paths(inputs: list[str], output: str) -> list[Path]:
    out = Path(output)
    if len(inputs) == 1 and not out.is_dir():
        outs = [out]
    else:
        outs = _folder_outputs(inputs, out)
    for i, o in zip(inputs, outs):
        if o.exists() and Path(i).exists() and o.samefile(i):
            raise CivicError(f"{o}: the output would overwrite its input")
        _same_format(i, o)
    return outs


def _same_format(src: str, dst: Path) -> None:
    """A replay writes each recording back in its own format: an output named for the other
    format is refused rather than written mislabelled."""
    from civic.wire import is_pcapng

    try:
        with open(src, "rb") as fh:
            ng = is_pcapng(fh.read(4))
    except OSError:
        return                                  # the reader says what is wrong with the input
    want = ".pcapng" if ng else ".pcap"
    if dst.suffix in (".pcap", ".pcapng") and dst.suffix != want:
        raise CivicError(f"{dst}: civic replay keeps {src}'s format ({want[1:]}): name the output {want}")


def _folder_outputs(inputs: list[str], out: Path) -> list[Path]:
    if out.exists() and not out.is_dir():
        raise CivicError(f"{out}: several inputs need an output folder")
    names = [Path(i).name for i in inputs]
    if len(set(names)) != len(names):
        raise CivicError("inputs share a file name; they would overwrite each other in the output folder")
    out.mkdir(parents=True, exist_ok=True)
    return [out / n for n in names]


def run(args) -> int:
    from civic.entries import load_entries
    from civic.replay import replay_files

    entries = load_entries(args.entries)
    outs = output_paths(args.inputs, args.output)
    events = [] if args.events or args.timeline else None
    stats = replay_files([Path(i) for i in args.inputs], outs, entries, args.entries, args.target, args.pipeline,
                         events)
    if args.events:
        from civic.events import write_events
        write_events(args.events, events)
        print(f"{len(events)} verdict changes -> {args.events}")
    if args.timeline:
        from civic.timeline import plot_timeline
        plot_timeline(events, args.timeline, end_t=stats.get("t_end"))
        print(f"class timeline -> {args.timeline}")
    print(f"replayed {stats['frames']} frames ({stats['plant']} plant messages, "
          f"{stats['evaluated']} with a verdict) from {len(outs)} file(s) -> {args.output}")
    if stats.get("missing"):
        print(f"warning: {stats['missing']} frames did not come out of the switch (left out of the output)")
    return 0
