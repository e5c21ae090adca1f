"""The profiles' examples per property: ``HYPOTHESIS_MAX_EXAMPLES`` replaces the profile's count, a bad value is
refused with what is allowed, and unset the profile keeps its own (``ci`` 3, ``thorough`` 60, as registered)."""

from __future__ import annotations

import pytest
from _profiles import profile
from hypothesis import settings


@pytest.mark.parametrize("name", ["ci", "thorough"])
def test_max_examples_from_the_environment(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("HYPOTHESIS_PROFILE", name)
    monkeypatch.delenv("HYPOTHESIS_MAX_EXAMPLES", raising=False)
    own = settings.get_profile(name).max_examples
    assert profile().max_examples == own
    monkeypatch.setenv("HYPOTHESIS_MAX_EXAMPLES", str(own + 5))
    assert profile().max_examples == own + 5
    # the profile's other settings are kept (thorough keeps its database, ci has none)
    assert (profile().database is None) == (settings.get_profile(name).database is None)


@pytest.mark.parametrize("raw", ["0", "-2", "many", "2.5"])
def test_a_bad_max_examples_is_refused(raw: str, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("HYPOTHESIS_MAX_EXAMPLES", raw)
    with pytest.raises(ValueError, match=r"HYPOTHESIS_MAX_EXAMPLES.*positive integer"):
        profile()
