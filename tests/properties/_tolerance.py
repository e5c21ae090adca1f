"""The tolerance of the recovery property: a stated function of the setup's noise and declared errors.

For every check of a family (identified parameter, curve, shift line, BSFC map) the allowed error is

    FAMILYWISE * (floor + max(noise, NOISE_FLOOR) * k_sigma_at_paper) + systematic

* ``floor``: the check's ``ideal`` tolerance for the drawn setup, i.e. what a chain without noise allows:
  0.1 % where the fit is exact, the telemetry converter's step propagated through the fit (3 sigma,
  ``_quantisation_bound``) and the stated bounds of intercepts and located points otherwise;
* ``noise * k_sigma_at_paper``: the check's ``realistic`` tolerance taken as k standard errors of the
  estimate at the paper setup's noise (the engineering tolerance the paper setup passes), scaled by the
  drawn noise multiplier, since every fit here is linear in the noisy samples and its standard error
  grows in proportion to their noise (0-3x the paper's). The imperfections the multiplier does not
  scale (sensor bandwidths, wire quantisation, clock drift, frame drops, a shorter campaign than the
  paper's) keep a share of it: ``NOISE_FLOOR`` (a quarter) of the paper's k sigma at least;
* ``systematic``: the gain and offset errors the drawn setup declares, propagated as the validation's
  GUM-like budget does (``_budget``: first-order sensitivities of each parameter; a transmission
  parameter's through its fit's own points, ``validation.transmission_budget``).

Each part is a bound at about three standard deviations. A property judges hundreds of checks a run (and
thousands in the ``thorough`` profile), where 3-sigma bounds would fail by chance: the sum is taken at
``FAMILYWISE`` (1.5) times, i.e. about 4.5 sigma, a chance exceedance of ~1e-5 per check (the systematic
part is a worst case already and is not widened). A finding pinned as an ``@example`` is also checked at the
plain noise-free bound ``floor + systematic`` (:func:`noise_free_checks`), which its fix must meet.

The three parts come from :mod:`benchtwin.validation.parameters` (validation code, which holds the truth),
never from the identification under test.
"""

from __future__ import annotations

import math

from benchtwin.config.setup import SetupConfig
from benchtwin.config.vehicle import VehicleConfig
from benchtwin.identification._fit import IdentificationResult
from benchtwin.validation.parameters import _budget, _systematic, compare_with_truth, truth_expectations
from benchtwin.validation.report import Check

#: the share of the paper setup's noise tolerance kept at zero noise (see the module docstring)
NOISE_FLOOR = 0.25
#: 3-sigma bounds taken to about 4.5 sigma for a property judged over many checks (see the module docstring)
FAMILYWISE = 1.5


def property_checks(result: IdentificationResult, vehicle: VehicleConfig, setup: SetupConfig, noise: float,
                    gears: list[int] | None, groups: set[str], *, noise_free: bool = False) -> list[Check]:
    """The family's checks (no R^2) with the property's tolerance in place of the profile's.

    ``noise_free``: the plain bound ``floor + systematic`` instead (for a setup without noise).
    """
    ideal = {c.name: c for c in compare_with_truth(result, vehicle, profile="ideal", gears=gears, setup=setup)}
    bare = {c.name: c for c in compare_with_truth(result, vehicle, profile="realistic", gears=gears, setup=None)}
    real = compare_with_truth(result, vehicle, profile="realistic", gears=gears, setup=setup)
    budget = _budget(setup)
    declared = {e.key: _systematic(e, result, budget) for e in truth_expectations(vehicle) if e.systematic is not None}
    out = []
    for c in real:
        if c.group not in groups:
            continue
        # scalar parameters: their declared sensitivities; curves (the BSFC map): what the profile adds
        systematic = declared.get(c.name, max(c.tolerance - bare[c.name].tolerance, 0.0))
        tol = FAMILYWISE * (ideal[c.name].tolerance + max(noise, NOISE_FLOOR) * bare[c.name].tolerance) + systematic
        if noise_free:
            tol = ideal[c.name].tolerance + systematic
        ok = bool(math.isfinite(c.error) and abs(c.error) <= tol)
        out.append(Check(c.group, c.name, c.identified, c.truth, c.error, tol, c.mode, c.unit, ok, c.note))
    return out
