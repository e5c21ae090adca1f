"""Property tests: their directory on the import path, and the hypothesis profiles (see ``_profiles``)."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

import _profiles  # noqa: F401  (registers the ``ci`` and ``thorough`` profiles)
