"""Folders the tests read: the repository's scenarios and models, the shared real data."""

from pathlib import Path

#: The repository root.
ROOT = Path(__file__).resolve().parents[1]
#: Bundled scenarios.
SCENARIOS = ROOT / "scenarios"
#: Bundled sensor models.
MODELS = ROOT / "models"
#: Real recordings shared beside the repository (tests using them skip when absent).
SHARED_DATA = ROOT.parent / "shared" / "data"
