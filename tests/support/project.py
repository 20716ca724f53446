"""Where the tests find the project and the shared data, wherever a test file sits below tests/."""
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]          # the repository
SHARED_DATA = ROOT.parent / "shared" / "data"        # real recordings beside the repository (../shared/data)
