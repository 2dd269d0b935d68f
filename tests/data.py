"""Where the bundled recordings are."""
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TRAINING = ROOT / "traces" / "training"
DIAGNOSE = ROOT / "traces" / "diagnose"
