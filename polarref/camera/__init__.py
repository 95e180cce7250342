"""Camera models with angular (theta, phi) pixel coordinates; see :mod:`polarref.camera.core`."""

from polarref.camera.core import Camera, angular_from_ray, ray_from_angular
from polarref.camera.models import MODELS
from polarref.camera.noise import (angular_covariance, phi_min_radius_px, phi_sigma,
                                   phi_usable)

__all__ = ["Camera", "MODELS", "angular_from_ray", "ray_from_angular", "angular_covariance",
           "phi_sigma", "phi_usable", "phi_min_radius_px"]
