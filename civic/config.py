"""Monitor configuration (`configs/monitors.toml`): what to watch, not how to classify."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from civic.errors import CivicError
from civic.files import read_toml
from civic.wire import DEFAULT_PLANT_PREFIX, DEFAULT_UDP_PORT, MAX_MONITORS, SIGNALS, parse_prefix

LEVEL_SIGNALS = ("l1", "l2", "l3", "l4")
STEP_FIELDS = ("dp1", "dv1", "dv2")          # command steps since the plant's previous message
PRECONDITION_FIELDS = SIGNALS + STEP_FIELDS
KINDS = ("slope", "balance", "limit")
MIN_WINDOW, MAX_WINDOW = 2, 128
MAX_HOLD = 255
MAX_FLOWS = 2                                # flow terms of a balance monitor
DEFAULT_MONITORS = Path(__file__).resolve().parent.parent / "configs" / "monitors.toml"


@dataclass
class Monitor:
    """One monitor: a level signal, a window, a precondition and, optionally, the two levels
    whose difference drives the tank's inflow (compensated, docs/pipeline.md 3a).

    `kind` "slope" classifies the level's slope (the test monitors), "balance" the tank's
    mass-balance residual over the model components named in `flows`, banded by the
    expected flow of the `band` component (pipeline.md 3b), "limit" the level's value.
    `hold`: a class is written once the table gave it on that many consecutive messages.
    `limits` (limit monitors): the values from which on the class is warning and error (a
    warning limit above the error limit watches a low level).
    """

    name: str
    signal: str
    window: int
    precondition: dict[str, tuple[int, int]] = field(default_factory=dict)
    compensate: tuple[str, str] | None = None
    kind: str = "slope"
    hold: int = 1
    flows: tuple[str, ...] = ()
    band: str | None = None
    limits: dict[str, int] = field(default_factory=dict)

    def ranges(self) -> list[tuple[int, int]]:
        """Precondition as one inclusive range per field, in PRECONDITION_FIELDS order."""
        return [self.precondition.get(s, (0, 0xFFFF)) for s in PRECONDITION_FIELDS]


@dataclass
class MonitorConfig:
    monitors: list[Monitor]
    udp_port: int = DEFAULT_UDP_PORT
    plant_prefix: str = DEFAULT_PLANT_PREFIX


def check_int(value, what: str, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise CivicError(f"{what}: expected an integer, got {value!r}")
    if not lo <= value <= hi:
        raise CivicError(f"{what}: {value} is outside {lo}..{hi}")
    return value


def check_range(value, what: str, lo: int, hi: int) -> tuple[int, int]:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise CivicError(f"{what}: expected [lo, hi], got {value!r}")
    a = check_int(value[0], f"{what}[0]", lo, hi)
    b = check_int(value[1], f"{what}[1]", lo, hi)
    if a > b:
        raise CivicError(f"{what}: empty range [{a}, {b}]")
    return a, b


def parse_precondition(raw, what: str) -> dict[str, tuple[int, int]]:
    if not isinstance(raw, dict):
        raise CivicError(f"{what}: expected a table of field = [lo, hi]")
    out = {}
    for key, rng in raw.items():
        if key not in PRECONDITION_FIELDS:
            raise CivicError(f"{what}.{key}: unknown field (one of {', '.join(PRECONDITION_FIELDS)})")
        out[key] = check_range(rng, f"{what}.{key}", 0, 0xFFFF)
    return out


def parse_monitor(raw, what: str) -> Monitor:
    if not isinstance(raw, dict):
        raise CivicError(f"{what}: expected a table")
    for key in ("name", "signal", "window"):
        if key not in raw:
            raise CivicError(f"{what}: missing key '{key}'")
    name = raw["name"]
    if not isinstance(name, str) or not name:
        raise CivicError(f"{what}.name: expected a non-empty string")
    if raw["signal"] not in LEVEL_SIGNALS:
        raise CivicError(f"{what}.signal: {raw['signal']!r} is not one of {', '.join(LEVEL_SIGNALS)}")
    window = check_int(raw["window"], f"{what}.window", MIN_WINDOW, MAX_WINDOW)
    pre = parse_precondition(raw.get("precondition", {}), f"{what}.precondition")
    comp = raw.get("compensate")
    if comp is not None:
        if (not isinstance(comp, list) or len(comp) != 2 or not all(s in LEVEL_SIGNALS for s in comp)
                or comp[0] == comp[1]):
            raise CivicError(f"{what}.compensate: expected two different levels [plus, minus] "
                             f"from {', '.join(LEVEL_SIGNALS)}, got {comp!r}")
        comp = (comp[0], comp[1])
    kind = raw.get("kind", "slope")
    if kind not in KINDS:
        raise CivicError(f"{what}.kind: {kind!r} is not one of {', '.join(KINDS)}")
    hold = check_int(raw.get("hold", 1), f"{what}.hold", 1, MAX_HOLD)
    flows, band = parse_flows(raw, what, kind)
    if comp is not None and kind != "slope":
        raise CivicError(f"{what}.compensate: only slope monitors are compensated")
    limits = parse_limits(raw.get("limits"), what, kind)
    return Monitor(name=name, signal=raw["signal"], window=window, precondition=pre, compensate=comp,
                   kind=kind, hold=hold, flows=flows, band=band, limits=limits)


def parse_limits(raw, what: str, kind: str) -> dict[str, int]:
    """A limit monitor's thresholds {warning, error} in wire units (optional in entries files)."""
    if raw is None:
        return {}
    if kind != "limit":
        raise CivicError(f"{what}.limits: only limit monitors have limits")
    if not isinstance(raw, dict) or set(raw) != {"warning", "error"}:
        raise CivicError(f"{what}.limits: expected {{ warning = N, error = N }}")
    out = {k: check_int(raw[k], f"{what}.limits.{k}", 1, 0xFFFF) for k in ("warning", "error")}
    if out["warning"] == out["error"]:
        raise CivicError(f"{what}.limits: warning and error limits must differ")
    return out


def parse_flows(raw: dict, what: str, kind: str) -> tuple[tuple[str, ...], str | None]:
    """A balance monitor's flow terms: names of the plant model's links and pumps (1 or 2)."""
    flows, band = raw.get("flows"), raw.get("band")
    if kind != "balance":
        if flows is not None or band is not None:
            raise CivicError(f"{what}: flows/band belong to balance monitors (kind = \"balance\")")
        return (), None
    if (not isinstance(flows, list) or not 1 <= len(flows) <= MAX_FLOWS
            or not all(isinstance(f, str) and f for f in flows) or len(set(flows)) != len(flows)):
        raise CivicError(f"{what}.flows: expected 1 to {MAX_FLOWS} distinct model component names, "
                         f"got {str(flows)[:60]}")
    if band is None:
        band = flows[-1]
    if band not in flows:
        raise CivicError(f"{what}.band: {band!r} is not one of the monitor's flows {flows}")
    return tuple(flows), band


def check_monitor_list(monitors: list[Monitor], what: str) -> None:
    if not monitors:
        raise CivicError(f"{what}: no monitors")
    if len(monitors) > MAX_MONITORS:
        raise CivicError(f"{what}: {len(monitors)} monitors, the verdict has room for {MAX_MONITORS}")
    names = [m.name for m in monitors]
    if len(set(names)) != len(names):
        raise CivicError(f"{what}: duplicate monitor names")


def parse_common(raw: dict, what: str) -> tuple[int, str]:
    port = check_int(raw.get("udp_port", DEFAULT_UDP_PORT), f"{what}: udp_port", 1, 65535)
    prefix = raw.get("plant_prefix", DEFAULT_PLANT_PREFIX)
    if not isinstance(prefix, str):
        raise CivicError(f"{what}: plant_prefix must be a string like '10.0.0.0/24'")
    parse_prefix(prefix)
    return port, prefix


def load_monitors(path: str | Path | None = None) -> MonitorConfig:
    """Read and validate a monitors TOML file; errors name the offending key."""
    path = Path(path) if path else DEFAULT_MONITORS
    raw = read_toml(path)
    port, prefix = parse_common(raw, str(path))
    items = raw.get("monitor")
    if not isinstance(items, list):
        raise CivicError(f"{path}: missing [[monitor]] tables")
    monitors = [parse_monitor(m, f"{path}: monitor[{i}]") for i, m in enumerate(items)]
    check_monitor_list(monitors, str(path))
    return MonitorConfig(monitors=monitors, udp_port=port, plant_prefix=prefix)
