"""The tests' helper modules (detector_fake_models) import from this folder."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
