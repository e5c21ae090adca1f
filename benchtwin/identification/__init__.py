"""Identification: the methods of the reverse-engineering paper, on a Recording only.

One module per subsystem, each with ``identify_*`` functions returning a
:class:`~benchtwin.identification._fit.FitResult` (estimate, standard error, 95 % interval, R^2,
points, segments). Identification never reads the Trace or the vehicle file; what it may know
about the car beforehand is its public :class:`~benchtwin.identification.specs.VehicleSpecs`.
"""

# benchtwin.config (vehicle.py) imports identification.specs, and specs imports config._base: load the config
# package first so that importing identification first does not meet a partially initialised module
import benchtwin.config  # noqa: F401  (import order, see above)
from benchtwin.identification._fit import FitResult, IdentificationResult, ParameterEstimate
from benchtwin.identification.specs import VehicleSpecs

__all__ = ["FitResult", "IdentificationResult", "ParameterEstimate", "VehicleSpecs"]
