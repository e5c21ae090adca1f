"""Identification: the methods of the reverse-engineering paper, on a Recording only.

One module per subsystem, each with ``identify_*`` functions returning a
:class:`~benchtwin.identification._fit.FitResult` (estimate, standard error, 95 % interval, R^2,
points, segments). Identification never reads the Trace or the vehicle file; what it may know
about the car beforehand is its public :class:`~benchtwin.config.specs.VehicleSpecs`.
"""

from benchtwin.config.specs import VehicleSpecs
from benchtwin.identification._fit import FitResult, IdentificationResult, ParameterEstimate

__all__ = ["FitResult", "IdentificationResult", "ParameterEstimate", "VehicleSpecs"]
