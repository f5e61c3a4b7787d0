"""Spatial Domain Mapping: the layer, its two implementations and a single-point explainer."""
from .explain import explain_point
from .layer import SDMFunction, SDMOutput, SpatialDomainMapping
from .result import MappingResult

__all__ = ["SpatialDomainMapping", "SDMFunction", "SDMOutput", "MappingResult", "explain_point"]
