"""Rich output shared by the commands: score tables (evaluate, crossval) and progress bars."""
from __future__ import annotations

from rich.console import Console
from rich.progress import Progress
from rich.table import Table

console = Console()


def progress_bar() -> Progress:
    """A transient progress bar on stderr: stdout keeps only results (and no blank line when piped)."""
    err = Console(stderr=True)
    return Progress(console=err, transient=True, disable=not err.is_terminal)


def score_table(title: str, s: dict) -> Table:
    """The paper's per-class table for one monitor."""
    t = Table(title=title, title_justify="left")
    for col in ("class", "precision", "recall", "F1", "accuracy", "support"):
        t.add_column(col, justify="right" if col != "class" else "left")
    for name, c in s["classes"].items():
        t.add_row(name, f"{c['precision']:.3f}", f"{c['recall']:.3f}", f"{c['f1']:.3f}",
                  f"{c['accuracy']:.3f}", str(c["support"]))
    t.add_row("macro F1", "", "", f"{s['macro_f1']:.3f}", f"{s['accuracy']:.3f}", str(s["n"]), style="bold")
    return t
