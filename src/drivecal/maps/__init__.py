"""Flux and incremental-inductance maps of a calibrated motor, with their 95 % bands."""

from ._flux_maps import GRID_POINTS, MAPS, FluxMaps, MapBand, flux_maps, covered_points

__all__ = ["GRID_POINTS", "MAPS", "FluxMaps", "MapBand", "flux_maps", "covered_points"]
