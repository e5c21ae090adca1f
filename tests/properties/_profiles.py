"""Hypothesis profiles of the property tests.

``ci`` (the default): few examples per property, so that tests/properties adds a few minutes to
``make test`` on 2 cores; derandomized and without a database, so every run (a clean clone's CI too) draws the
same examples. ``thorough``: many more examples, new ones each run, the example database in ``.hypothesis/``
(git-ignored), so a failure found once is replayed first by the next run; for nightly runs::

    HYPOTHESIS_PROFILE=thorough .venv/bin/python -m pytest tests/properties

``HYPOTHESIS_MAX_EXAMPLES=N`` replaces either profile's examples per property (a short try: ``thorough`` with 2 on
one family, ``-k battery``).

No test depends on timing (``deadline=None``). The tests take the profile with ``@profile()`` (from
``_profiles``), so the settings of the rest of the suite are left as they are.

The draws do not depend on which modules are loaded. Hypothesis (6.13x on) mixes into its draws, now and then, the
literals of the project's loaded source modules; which of benchtwin's modules a pytest worker has imported when a
property runs depends on the tests that ran before it there, so under ``pytest -n 2 --dist loadfile`` a derandomized
``ci`` example was not the same example from run to run (a converter draw failed only beside the sensor tests), and
every new literal anywhere in the package would move every property's draws. ``freeze_local_constants`` empties
that pool for this process (the library's own constants, 0, 1, NaN, the bounds, are kept).
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
def freeze_local_constants() -> None:
    """Make Hypothesis draw no literal of the project's loaded source modules (see the module's docstring).

    Hypothesis keeps that pool in ``hypothesis.internal.conjecture.providers``; the pool's getter is replaced by
    one returning an empty set of constants, and the cache of allowed constants cleared. A release older than the
    pool has nothing to freeze; one that draws constants some other way raises rather than let the draws silently
    depend on the imports again.
    """
    from hypothesis.internal.conjecture import providers

    if not hasattr(providers, "_get_local_constants"):
        if hasattr(getattr(providers, "HypothesisProvider", None), "_maybe_draw_constant"):
            raise RuntimeError("hypothesis draws constants without providers._get_local_constants: "
                               "review freeze_local_constants")
        return
    from hypothesis.internal.constants_ast import Constants

    empty = Constants()
    providers._get_local_constants = lambda: empty
    providers.CONSTANTS_CACHE.cache.clear()


freeze_local_constants()

settings.register_profile("ci", max_examples=3, phases=[Phase.explicit, Phase.reuse, Phase.generate],
                          derandomize=True, **{**_COMMON, "database": None})
settings.register_profile("thorough", max_examples=60, **_COMMON)


def profile(**overrides: object) -> settings:
    """The chosen profile (``HYPOTHESIS_PROFILE``, default ``ci``), for ``@settings(...)`` of a property.

    The profile is applied per test rather than loaded globally, so the other tests of the suite keep
    their own settings.
    """
    return settings(settings.get_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci")), **_max_examples(), **overrides)


def _max_examples() -> dict[str, int]:
    """``HYPOTHESIS_MAX_EXAMPLES=N`` (a positive integer) replaces the profile's examples per property: a short
    try of the ``thorough`` profile, or a longer night; unset, the profile's own count."""
    raw = os.environ.get("HYPOTHESIS_MAX_EXAMPLES", "").strip()
    if not raw:
        return {}
    if not raw.isdigit() or int(raw) < 1:
        raise ValueError(f"HYPOTHESIS_MAX_EXAMPLES = {raw!r}: allowed a positive integer (examples per property)")
    return {"max_examples": int(raw)}
