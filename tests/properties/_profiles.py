"""Hypothesis profiles of the property tests.

``ci`` (the default): few examples per property, so that tests/properties adds a few minutes to
``make test`` on 2 cores; the example database lives in ``.hypothesis/`` (git-ignored), so a failure found
once is replayed first by the next run. ``thorough``: many more examples, for nightly runs::

    HYPOTHESIS_PROFILE=thorough .venv/bin/python -m pytest tests/properties

No test depends on timing (``deadline=None``). The tests take the profile with ``@profile()`` (from
``_profiles``), so the settings of the rest of the suite are left as they are.
"""

from __future__ import annotations

import os
from pathlib import Path

from hypothesis import HealthCheck, Phase, settings
from hypothesis.database import DirectoryBasedExampleDatabase

_DB = DirectoryBasedExampleDatabase(str(Path(__file__).resolve().parents[2] / ".hypothesis" / "examples"))
_COMMON = {"deadline": None, "database": _DB, "print_blob": True,
           "suppress_health_check": [HealthCheck.too_slow, HealthCheck.data_too_large]}

# ci does not shrink a failure (each shrink step is a whole example): it reports the failing example as drawn,
# and ci draws the same examples every run (derandomize, no database: a clean clone's CI is reproducible);
# thorough draws new ones, keeps them in the database (a failure found is replayed first) and shrinks
settings.register_profile("ci", max_examples=3, phases=[Phase.explicit, Phase.reuse, Phase.generate],
                          derandomize=True, **{**_COMMON, "database": None})
settings.register_profile("thorough", max_examples=60, **_COMMON)


def profile(**overrides: object) -> settings:
    """The chosen profile (``HYPOTHESIS_PROFILE``, default ``ci``), for ``@settings(...)`` of a property.

    The profile is applied per test rather than loaded globally, so the other tests of the suite keep
    their own settings.
    """
    return settings(settings.get_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci")), **overrides)
