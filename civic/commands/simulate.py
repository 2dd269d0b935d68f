"""civic simulate: the plant simulator (test procedures, closed loop, open loop on recorded inputs)."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from civic.errors import CivicError
from civic.plant.figures import save_figure
from civic.plant.simulate import EPOCH, write_recording



def register(sub) -> None:
    p = sub.add_parser("simulate", help="simulate the plant: drain/fill tests, closed loop, or recorded inputs",
                       description="Simulate the plant model. SCENARIO is drain, fill or closed-loop; "
                                   "with --inputs or --like the model is run open loop on recorded commands.")
    p.add_argument("scenario", nargs="?", choices=("drain", "fill", "closed-loop"), metavar="SCENARIO",
                   help="drain | fill | closed-loop")
    p.add_argument("--model", metavar="FILE", help="model file (default: configs/plant.toml)")
    p.add_argument("--v0", type=float, help="start volume of T1..T3, L (drain 7.5, fill 3.0)")
    p.add_argument("--fault", metavar="vmN=C", help="manual valve closure, e.g. vm1=0.3 or vm2=warning")
    p.add_argument("--controller", choices=("mpc", "pi"), default="mpc")
    p.add_argument("--onset", type=float, metavar="S",
                   help="closed loop: the --fault comes on S seconds into the run (default: from the start); "
                        "with --plants and no --fault, plants cycle through fault-free, vm1 warning/error, "
                        "vm2 warning/error")
    p.add_argument("--duration", type=float, metavar="S", help="seconds (drain 18, fill 40, closed loop 600)")
    p.add_argument("--seed", type=int, help="random seed (noise, schedule)")
    p.add_argument("--no-noise", action="store_true", help="no sensor noise: deterministic output")
    p.add_argument("--src-ip", default="10.0.0.1", help="gateway address in the pcap (default 10.0.0.1)")
    p.add_argument("--plants", type=int, default=1, metavar="N",
                   help="N plants in one capture, gateways SRC_IP, SRC_IP+1, ..., messages interleaved; "
                        "plant k uses seed SEED+k, and drain/fill without --fault cycle the classes "
                        "normal, warning, error over the plants (default 1)")
    p.add_argument("-o", "--output", metavar="OUT.pcap|OUT.pcapng|OUT.csv")
    p.add_argument("--plot", metavar="OUT.png")
    p.add_argument("--labels", metavar="LABELS.csv",
                   help="append labels rows (drain/fill: one per run; closed loop with --onset: one per run and "
                        "balance monitor, the format of traces/continuous/labels.csv)")
    p.add_argument("--schedule", metavar="TRUTH.json",
                   help="closed loop: setpoints and tests from a truth.json 'operation' list")
    p.add_argument("--truth", metavar="OUT.json", help="closed loop: write the operation log (truth.json style)")
    p.add_argument("--inputs", metavar="IN.csv|IN.pcap", help="open loop on these recorded commands")
    p.add_argument("--like", metavar="REC.pcap", help="replay a recording's commands and start state; RMSE table")
    p.add_argument("--init-samples", type=int, metavar="N",
                   help="samples used to estimate unmeasured states (RMSE is over the samples after N; "
                        "default 1, or 50 when a tank is unmeasured)")
    p.set_defaults(func=run)


def default_model_path() -> Path:
    here = Path("configs/plant.toml")
    if here.exists():
        return here
    from civic.plant.model import DATASHEET

    return DATASHEET


def run(args) -> int:
    from civic.plant.model import PlantModel

    from civic.wire import ip_to_int

    ip_to_int(args.src_ip)
    model = PlantModel.from_toml(args.model or default_model_path())
    if args.inputs and args.like:
        raise CivicError("give --inputs or --like, not both")
    if args.inputs or args.like:
        if args.plants != 1:
            raise CivicError("--plants applies to simulated scenarios, not --inputs/--like")
        if args.scenario:
            raise CivicError("SCENARIO and --inputs/--like exclude each other")
        return _open_loop(args, model)
    if not args.scenario:
        raise CivicError("give a SCENARIO (drain, fill, closed-loop) or --inputs/--like")
    if not args.output:
        raise CivicError("-o OUT.pcap|OUT.pcapng|OUT.csv is required")
    _check_output(args.output)
    if args.plants != 1:
        return _fleet(args, model)
    if args.duration is not None and not args.duration > 0:
        raise CivicError("--duration must be > 0")
    from civic.plant.procedures import (append_label, label_row, make_procedure, parse_fault,
                                        apply_faults, run_procedure)

    faults = parse_fault(args.fault)
    noise = not args.no_noise
    if args.onset is not None and args.scenario != "closed-loop":
        raise CivicError("--onset applies to closed-loop only")
    if args.scenario == "closed-loop":
        if args.v0 is not None:
            raise CivicError("--v0 applies to the drain and fill tests only")
        if args.labels and args.onset is None:
            raise CivicError("--labels in closed loop needs --onset (the time the fault comes on)")
        from civic.plant.control import run_closed_loop, schedule_from_truth

        m = apply_faults(model, faults) if faults and args.onset is None else model
        onset = (args.onset, apply_faults(model, faults)) if args.onset is not None else None
        schedule, duration = None, args.duration
        if args.schedule:
            schedule, sched_dur = schedule_from_truth(args.schedule)
            duration = duration if duration is not None else sched_dur
        duration = 600.0 if duration is None else duration
        with _progress(duration) as prog:
            res = run_closed_loop(m, duration, controller=args.controller, seed=args.seed, noise=noise,
                                  progress=prog, controller_model=model, schedule=schedule, onset=onset)
        if args.truth:
            _write_truth(args.truth, res, args, faults, duration)
        t, signals = res.t, res.signals
        extra = f", {sum(1 for o in res.operation if o[1].endswith(':run'))} embedded test(s)"
    else:
        if args.controller != "mpc":
            raise CivicError("--controller applies to closed-loop only")
        if args.schedule or args.truth:
            raise CivicError("--schedule and --truth apply to closed-loop only")
        proc = make_procedure(model, args.scenario, args.v0, faults, args.duration)
        signals = run_procedure(proc, noise=noise, seed=args.seed)
        t = proc.t
        extra = f", v0 {proc.v0:g} L, closure {proc.closure:g}"
    write_recording(args.output, model, t, signals, args.src_ip, args.seed)
    if args.labels and args.scenario == "closed-loop":
        for row in closed_loop_labels(Path(args.output).name, faults, args.onset, args.seed, args.src_ip):
            append_label(args.labels, row)
    elif args.labels:
        append_label(args.labels, label_row(Path(args.output).name, proc, args.seed, args.src_ip))
    if args.plot:
        _plot_run(args.plot, model, t, signals, f"{args.scenario} ({model.name})")
    print(f"simulated {args.scenario}: {len(t)} samples ({t[-1] + model.dt:g} s){extra} -> {args.output}")
    return 0


# ---------------------------------------------------------------------------------------
def _fleet(args, model) -> int:
    """N plants of one scenario in one pcap, one gateway address each, messages interleaved in time."""
    from civic.plant.procedures import (FAULT_CLASSES, append_label, apply_faults, label_row, make_procedure,
                                        parse_fault, run_procedure)
    from civic.plant.simulate import WIRE_COLUMNS, to_wire
    from civic.report import progress_bar
    from civic.wire import build_frames, int_to_ip, ip_to_int, write_pcap

    n = args.plants
    first = ip_to_int(args.src_ip)
    if not 1 <= n <= 256 or (first & 0xFF) + n > 256:
        raise CivicError(f"--plants {n} from {args.src_ip}: the gateways must share the /24 (at most "
                         f"{256 - (first & 0xFF)} plants)")
    if not args.output.endswith((".pcap", ".pcapng")):
        raise CivicError("--plants writes one capture: the output must end in .pcap or .pcapng")
    if args.plot:
        raise CivicError("--plot shows one plant: leave out --plants")
    if args.duration is not None and not args.duration > 0:
        raise CivicError("--duration must be > 0")
    scenario, base_seed = args.scenario, args.seed if args.seed is not None else 0
    fixed = parse_fault(args.fault)
    if scenario == "closed-loop" and (args.v0 is not None or args.schedule or args.truth):
        raise CivicError("--plants closed-loop takes no --v0, --schedule or --truth")
    if scenario == "closed-loop" and args.labels and args.onset is None:
        raise CivicError("--labels in closed loop needs --onset (the time the fault comes on)")
    from civic.continuous import FAULTS
    cycle = [{}] + [{valve: c} for valve, classes in FAULTS.values() for c in classes.values()]
    valve = {"drain": "vm1", "fill": "vm2"}.get(scenario)
    times, frames, rows = [], [], []
    with progress_bar() as progress:
        task = progress.add_task(f"simulating {n} plants", total=n)
        for k in range(n):
            seed, ip = base_seed + k, int_to_ip(first + k)
            faults = fixed or ({} if valve is None else
                               {valve: FAULT_CLASSES[scenario][("normal", "warning", "error")[k % 3]]})
            if scenario == "closed-loop":
                from civic.plant.control import run_closed_loop
                if args.onset is not None and not fixed:
                    faults = cycle[k % len(cycle)]
                m = apply_faults(model, faults) if faults and args.onset is None else model
                onset = (args.onset, apply_faults(model, faults)) if args.onset is not None else None
                res = run_closed_loop(m, args.duration or 600.0, controller=args.controller, seed=seed,
                                      noise=not args.no_noise, controller_model=model, onset=onset)
                t, signals = res.t, res.signals
                if args.labels:
                    rows += closed_loop_labels(Path(args.output).name, faults, args.onset, seed, ip)
            else:
                proc = make_procedure(model, scenario, args.v0, faults, args.duration)
                t, signals = proc.t, run_procedure(proc, noise=not args.no_noise, seed=seed)
                rows.append(label_row(Path(args.output).name, proc, seed, ip))
            fields = to_wire(model, signals)
            seq0 = int(np.random.default_rng(seed).integers(0, 2**32))
            f = build_frames({c: fields[c] for c in WIRE_COLUMNS}, src_ip=ip, seq0=seq0)
            frames += [row.tobytes() for row in f]
            times.append(EPOCH + np.asarray(t) + k * model.dt / n)      # plant k sends k/N of a period later
            progress.advance(task)
    times = np.concatenate(times)
    order = np.argsort(times, kind="stable")
    write_pcap(args.output, times[order], [frames[i] for i in order])
    if args.labels:
        for row in rows:
            append_label(args.labels, row)
    print(f"simulated {scenario} on {n} plants ({args.src_ip} .. {int_to_ip(first + n - 1)}): "
          f"{len(frames)} messages interleaved -> {args.output}")
    return 0


def closed_loop_labels(file: str, faults: dict, onset: float, seed, src_ip: str) -> list[dict]:
    """One row per balance monitor: the class it should report from the onset on (columns of
    traces/continuous/labels.csv)."""
    from civic.continuous import FAULTS, SCENARIO
    from civic.plant.procedures import class_of

    rows = []
    fault = next(iter(faults), None)
    for monitor, (valve, _) in FAULTS.items():
        cls = class_of(SCENARIO[monitor], faults.get(valve, 0.0))
        rows.append({"file": file, "scenario": "closed_loop", "monitor": monitor, "class": cls,
                     "fault": fault.upper() if fault else "none", "closure": max(faults.values(), default=0.0),
                     "onset_s": "" if not faults else onset, "unit_seed": "", "seed": seed, "src_ip": src_ip,
                     "set": "simulated"})
    return rows


def _check_output(path: str) -> None:
    if not path.endswith((".pcap", ".pcapng", ".csv")):
        raise CivicError(f"{path}: output must end in .pcap, .pcapng or .csv")
    parent = Path(path).parent
    if not parent.is_dir():
        raise CivicError(f"{path}: folder {parent} does not exist")


class _progress:
    """A rich progress bar on a terminal for long runs; silent otherwise."""

    def __init__(self, duration: float):
        self.on = duration >= 120 and sys.stderr.isatty()

    def __enter__(self):
        if not self.on:
            return None
        from rich.console import Console
        from rich.progress import BarColumn, Progress, TimeRemainingColumn

        self.p = Progress("simulating", BarColumn(), "{task.percentage:>3.0f}%", TimeRemainingColumn(),
                          console=Console(stderr=True), transient=True)
        self.p.__enter__()
        self.task = self.p.add_task("sim", total=1.0)
        return lambda k, n: self.p.update(self.task, completed=k / max(n, 1))

    def __exit__(self, *exc):
        if self.on:
            self.p.__exit__(*exc)
        return False


def _write_truth(path: str, res, args, faults: dict, duration: float) -> None:
    import json

    truth = {"mechanism": "closure" if faults else "none", "faults": faults, "controller": args.controller,
             "seed": args.seed, "duration_s": duration, "epoch_us": int(EPOCH * 1e6),
             "time_base": "seconds from the first message", "operation": res.operation}
    try:
        with open(path, "w") as fh:
            json.dump(truth, fh, indent=1)
    except OSError as exc:
        raise CivicError(f"cannot write {path}: {exc.strerror}") from exc


def _open_loop(args, model) -> int:
    from civic.plant.simulate import (SHORT_GAP, initial_state, load_recording, outside_range, regularise,
                                      simulate, unmeasured_tanks, unreadable_lines, with_unreadable_marked)

    src = args.inputs or args.like
    rec = load_recording(src, model)
    if len(rec.t) < 2:
        raise CivicError(f"{src}: needs at least 2 samples")
    step = np.median(np.diff(rec.t))
    if abs(step - model.dt) > 0.01 * model.dt:
        raise CivicError(f"{src}: sample time {step:g} s differs from the model's dt {model.dt:g} s")
    if np.any(np.diff(rec.t) <= 0):
        raise CivicError(f"{src}: time stamps are not increasing")
    # lost messages: the samples stay at their times, and the readings filled in for them are not scored
    rec = regularise(rec, model.dt)
    lost = int(rec.gaps.sum())
    rec = with_unreadable_marked(rec, model)
    n = len(rec.t)
    if lost:
        print(f"civic simulate: warning: {src}: {lost} samples lost in runs longer than {SHORT_GAP}: left out "
              f"of the RMSE, the simulation started again from the readings after each (where every tank is "
              f"measured)", file=sys.stderr)
    for line in unreadable_lines(rec):
        print(f"civic simulate: warning: {src}: {line}", file=sys.stderr)
    missing = [i for i in model.input_names if i not in rec.signals]
    if missing:
        raise CivicError(f"{src}: no column for input(s) {', '.join(missing)}")
    for line in outside_range(model, rec.signals):
        print(f"civic simulate: warning: {src}: {line}", file=sys.stderr)
    unmeasured = unmeasured_tanks(model, rec.signals)
    N = args.init_samples if args.init_samples is not None else (50 if unmeasured else 1)
    if not 1 <= N < n:
        raise CivicError(f"--init-samples must lie in 1..{n - 1}")
    if N < 2 and unmeasured:
        raise CivicError(f"--init-samples {N} cannot estimate the unmeasured tank(s) {', '.join(unmeasured)}: "
                         "give 2 or more")
    if args.output:
        _check_output(args.output)
    t = np.arange(n) * model.dt
    init = {k: np.asarray(v)[:N] for k, v in rec.signals.items()}
    x0 = initial_state(model, init, N)
    inputs = {k: rec.signals[k] for k in model.input_names}
    sim = simulate(model, t, inputs, x0)
    if rec.lost.any() and not unmeasured:
        # the commands in a lost stretch are unknown: after it, start again from the readings
        for a in np.flatnonzero(rec.lost[:-1] & ~rec.lost[1:]) + 1:
            b = a + int(np.argmax(rec.lost[a:])) if rec.lost[a:].any() else n
            x0a = initial_state(model, {k: np.asarray(v)[a:a + 1] for k, v in rec.signals.items()}, 1)
            part = simulate(model, t[a:b] - t[a], {k: np.asarray(v)[a:b] for k, v in inputs.items()}, x0a)
            for name in model.signal_names:
                sim[name][a:b] = part[name]
    rows = []
    for name in model.signal_names:
        if name in rec.signals:
            e = (sim[name] - np.asarray(rec.signals[name]))[N:][~rec.gaps[N:]]
            rows.append((name, float(np.sqrt(np.mean(e ** 2))), float(np.max(np.abs(e)))))
    print(f"open loop on {src}: {n} samples, initial state from the first sample"
          + (f", unmeasured states from the first {N}" if N > 1 else ""))
    print("x0: " + ", ".join(f"{k}={v:.4g}" for k, v in x0.items()))
    print(f"{'signal':<8} {'RMSE':>10} {'max |err|':>10}   (samples {N}..{n - 1})")
    for name, r, mx in rows:
        print(f"{name:<8} {r:>10.4g} {mx:>10.4g}")
    if args.output:
        write_recording(args.output, model, t, sim, args.src_ip, args.seed)
        print(f"-> {args.output}")
    if args.plot:
        _plot_compare(args.plot, model, t, rec.signals, sim, Path(src).name)
    return 0


def _plot_run(path, model, t, signals, title):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for name in model.signal_names:
        a1.plot(t, signals[name], label=name, lw=1)
    a1.set_ylabel("sensor")
    a1.legend(loc="best", fontsize=8)
    for name in model.input_names:
        a2.plot(t, signals[name], label=name, lw=1)
    a2.set_ylabel("command")
    a2.set_xlabel("t (s)")
    a2.legend(loc="best", fontsize=8)
    save_figure(fig, path, title)


def _plot_compare(path, model, t, recorded, sim, title):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [n for n in model.signal_names if n in recorded]
    fig, axes = plt.subplots(len(names) + 1, 1, figsize=(9, 2.2 * (len(names) + 1)), sharex=True, squeeze=False)
    for ax, name in zip(axes[:, 0], names):
        ax.plot(t, recorded[name], lw=0.8, color="0.5", label="recorded")
        ax.plot(t, sim[name], lw=1.2, color="C0", label="simulated")
        ax.set_ylabel(name)
        ax.legend(loc="best", fontsize=8)
    ax = axes[-1, 0]
    for name in model.input_names:
        ax.plot(t, sim[name], lw=1, label=name)
    ax.set_ylabel("command")
    ax.set_xlabel("t (s)")
    ax.legend(loc="best", fontsize=8)
    save_figure(fig, path, f"{title}: recorded vs {model.name}")
