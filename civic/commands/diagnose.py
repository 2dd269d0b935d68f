"""civic diagnose: what does a recording show that the nominal plant model leaves out?"""
from __future__ import annotations

import sys
from pathlib import Path

from civic.errors import CivicError


def register(sub) -> None:
    p = sub.add_parser(
        "diagnose", help="find mechanisms (leaks, dead times, offsets...) the model lacks",
        description="Compare a recording with the nominal plant model (mass-balance equation error "
                    "when every tank is measured, open-loop simulation otherwise), calibrate the "
                    "coefficients within +-5 %, localise the mismatch, fit the mechanism catalogue "
                    "and keep what is significant on held-out data.")
    p.add_argument("recording", metavar="RECORDING", help="pcap (wire format) or CSV (t_s, inputs, signals)")
    p.add_argument("--model", metavar="FILE", help="nominal model (default: configs/plant.toml)")
    p.add_argument("--json", metavar="REPORT.json", help="write the report")
    p.add_argument("--plot", metavar="FIT.png", help="recorded vs nominal vs improved, mismatch shaded")
    p.add_argument("--write-model", metavar="IMPROVED.toml", help="write the improved model")
    p.add_argument("--plant", metavar="IP", help="gateway address in a multi-plant pcap (default: the first)")
    p.add_argument("--init-samples", type=int, default=None, metavar="N",
                   help="samples used to estimate unmeasured initial states (default 1, or 50 when "
                        "some tanks are unmeasured); RMSE is over the samples after N")
    p.add_argument("--window", type=float, default=5.0, metavar="S",
                   help="mass-balance window, seconds (default 5)")
    p.add_argument("-j", "--jobs", type=int, default=None, metavar="N",
                   help="worker processes for the independent fits (default: the CPUs this process "
                        "may use; the report does not depend on it)")
    p.add_argument("-q", "--quiet", action="store_true", help="no table on stdout")
    p.set_defaults(func=run)


def _check_out(path: str | None, suffixes: tuple[str, ...]) -> None:
    if path is None:
        return
    if not path.endswith(suffixes):
        raise CivicError(f"{path}: expected a {' or '.join(suffixes)} file")
    parent = Path(path).parent
    if not parent.is_dir():
        raise CivicError(f"{path}: folder {parent} does not exist")


def run(args) -> int:
    from civic.commands.simulate import default_model_path
    from civic.diagnose import data
    from civic.diagnose.fit import diagnose
    from civic.diagnose.report import build_report, plot, print_summary, write_json
    from civic.plant.model import PlantModel
    from civic.plant.simulate import outside_range, unreadable_lines

    _check_out(args.json, (".json",))
    _check_out(args.plot, (".png", ".pdf", ".svg"))
    _check_out(args.write_model, (".toml",))
    if not args.window > 0:
        raise CivicError("--window must be > 0")
    if args.jobs is not None and args.jobs < 1:
        raise CivicError("--jobs must be >= 1")
    model = PlantModel.from_toml(args.model or default_model_path())
    rec = data.load(args.recording, model, args.plant)
    for line in outside_range(model, rec.signals):
        print(f"civic diagnose: warning: {args.recording}: {line}", file=sys.stderr)
    for line in unreadable_lines(rec):
        print(f"civic diagnose: warning: {args.recording}: {line}", file=sys.stderr)
    from civic.diagnose.compare import fully_measured

    full = fully_measured(model, rec)
    n_init = args.init_samples if args.init_samples is not None else (1 if full else 50)
    if not 1 <= n_init < len(rec.t) // 2:
        raise CivicError(f"--init-samples must lie in 1..{len(rec.t) // 2 - 1}")
    with _Progress() as prog:
        diag = diagnose(model, rec, progress=prog, window_s=args.window, n_init=n_init, jobs=args.jobs)
    rep = build_report(diag, rec, n_init=n_init, skip=0 if full else n_init)
    if not args.quiet:
        print_summary(rep)
    if args.json:
        write_json(rep, args.json)
    if args.plot:
        plot(rep, diag, rec, args.plot)
    if args.write_model:
        try:
            diag.model_improved.to_toml(args.write_model)
        except OSError as exc:
            raise CivicError(f"cannot write {args.write_model}: {exc.strerror}") from exc
    outs = [x for x in (args.json, args.plot, args.write_model) if x]
    if outs and not args.quiet:
        print("-> " + ", ".join(outs))
    return 0


class _Progress:
    """A rich progress bar on stderr for long runs on a terminal; silent otherwise."""

    def __init__(self):
        self.on = sys.stderr.isatty()

    def __enter__(self):
        if not self.on:
            return None
        from rich.console import Console
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        self.p = Progress(TextColumn("diagnosing"), BarColumn(), TextColumn("{task.description}"),
                          TimeElapsedColumn(), console=Console(stderr=True), transient=True)
        self.p.__enter__()
        self.task = self.p.add_task("", total=1.0)
        return lambda k, n, what="": self.p.update(self.task, completed=k / max(n, 1), description=what)

    def __exit__(self, *exc):
        if self.on:
            self.p.__exit__(*exc)
        return False
