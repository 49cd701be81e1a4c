"""The vehicle's config under its name before (``vehicle_config``): a model of a user's written
against ``from sim_vehicles.models.spec import VehicleSpec, VehicleSpecError`` still loads.
"spec" is a run's requirements now (``docs/specs.md``); new code imports ``vehicle_config``."""

from sim_vehicles.models.vehicle_config import VehicleConfig as VehicleSpec
from sim_vehicles.models.vehicle_config import VehicleConfigError as VehicleSpecError

__all__ = ["VehicleSpec", "VehicleSpecError"]
