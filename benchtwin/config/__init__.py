"""Typed, validated models of the scenario files.

Three kinds of TOML file describe a run: a *vehicle* file (every true parameter of the plant), a
*setup* file (the bench: each sensor, its range, rate, imperfections, bus and address) and a
*campaign* file (the tests, the plant rate and the seed). Each loads into a pydantic model; a bad
file raises :class:`~benchtwin.errors.ConfigError` with one line per problem naming the file, the
key, the value and what is allowed.
"""

from benchtwin.config._base import StrictModel, load_model, scenario_path, validate_data
from benchtwin.config.campaign import CampaignConfig, load_campaign
from benchtwin.config.specs import VehicleSpecs
from benchtwin.config.vehicle import VehicleConfig, load_vehicle

__all__ = [
    "CampaignConfig",
    "StrictModel",
    "VehicleConfig",
    "VehicleSpecs",
    "load_campaign",
    "load_model",
    "load_vehicle",
    "scenario_path",
    "validate_data",
]
from benchtwin.config.setup import SetupConfig, load_setup

__all__ += ["SetupConfig", "load_setup"]
