"""Monitor configuration (`configs/monitors.toml`): what to watch, not how to classify."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from civic.errors import CivicError
from civic.files import read_toml
from civic.wire import DEFAULT_PLANT_PREFIX, DEFAULT_UDP_PORT, MAX_MONITORS, SIGNALS, parse_prefix

LEVEL_SIGNALS = ("l1", "l2", "l3", "l4")
MIN_WINDOW, MAX_WINDOW = 2, 128
DEFAULT_MONITORS = Path(__file__).resolve().parent.parent / "configs" / "monitors.toml"


@dataclass
class Monitor:
    """One monitor: a level signal, a window, an instantaneous precondition and, optionally,
    the two levels whose difference drives the tank's inflow (compensated, docs/pipeline.md 3a)."""

    name: str
    signal: str
    window: int
    precondition: dict[str, tuple[int, int]] = field(default_factory=dict)
    compensate: tuple[str, str] | None = None

    def ranges(self) -> list[tuple[int, int]]:
        """Precondition as one inclusive range per wire field, in SIGNALS order."""
        return [self.precondition.get(s, (0, 0xFFFF)) for s in SIGNALS]


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
        if key not in SIGNALS:
            raise CivicError(f"{what}.{key}: unknown field (one of {', '.join(SIGNALS)})")
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
    return Monitor(name=name, signal=raw["signal"], window=window, precondition=pre, compensate=comp)


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
