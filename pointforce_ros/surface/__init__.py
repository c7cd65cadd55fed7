"""pointforce_ros.surface: the equilibrium surface from depth-camera clouds (pure core)."""

from pointforce_ros.surface.equilibrium import (
    build_equilibrium_surface, equilibrium_surface, Scan, surface_from_cloud, SurfaceConfig,
    SurfaceReport)

__all__ = ['Scan', 'SurfaceConfig', 'SurfaceReport', 'build_equilibrium_surface',
           'equilibrium_surface', 'surface_from_cloud']
