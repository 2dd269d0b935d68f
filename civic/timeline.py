"""A fleet's class timeline: one row per plant, coloured by the class its verdicts say, from events."""
from __future__ import annotations

import ipaddress
from pathlib import Path

from civic.errors import CivicError

COLORS = {"normal": "tab:green", "warning": "tab:orange", "error": "tab:red"}


def plot_timeline(events: list[dict], path: str | Path, end_t: float | None = None) -> None:
    """Plants x time per monitor: each class from its change event to the next (or `end_t`)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not events:
        raise CivicError(f"{path}: no verdict changes to plot")
    t0 = min(e["t"] for e in events)
    end = max(max(e["t"] for e in events), end_t or 0.0)
    monitors = sorted({e["monitor"] for e in events})
    plants = sorted({e["plant"] for e in events}, key=lambda p: int(ipaddress.IPv4Address(p)))
    row = {p: i for i, p in enumerate(plants)}
    fig, axes = plt.subplots(1, len(monitors), figsize=(7 * len(monitors), 1.5 + 0.12 * len(plants)),
                             squeeze=False, sharey=True)
    for ax, monitor in zip(axes[0], monitors):
        mine = sorted((e for e in events if e["monitor"] == monitor), key=lambda e: (e["plant"], e["t"]))
        for i, e in enumerate(mine):
            nxt = mine[i + 1] if i + 1 < len(mine) and mine[i + 1]["plant"] == e["plant"] else None
            stop = nxt["t"] if nxt else end
            ax.barh(row[e["plant"]], max(stop - e["t"], 0.05), left=e["t"] - t0, height=0.8,
                    color=COLORS[e["to"]], lw=0)
        ax.set(title=f"{monitor}: class per plant (from verdict changes)", xlabel="time (s)",
               xlim=(0, end - t0 if end > t0 else 1))
    axes[0][0].set_yticks(range(len(plants)))
    axes[0][0].set_yticklabels(plants, fontsize=6 if len(plants) > 20 else 9)
    axes[0][0].invert_yaxis()
    axes[0][-1].legend(handles=[plt.Rectangle((0, 0), 1, 1, color=c, label=k) for k, c in COLORS.items()],
                       loc="upper left", bbox_to_anchor=(1.0, 1.0))
    fig.tight_layout()
    try:
        fig.savefig(path, dpi=110)
    except OSError as exc:
        raise CivicError(f"cannot write {path}: {exc.strerror}") from None
    finally:
        plt.close(fig)
