"""Spatial Domain Mapping: the layer, its two implementations, the gradient rule and a single-point explainer."""
from .explain import explain_point
from .flow import WINDOW_OFFSETS, dynamic_flow
from .layer import SDMFunction, SDMOutput, SpatialDomainMapping
from .result import MappingResult

__all__ = ["SpatialDomainMapping", "SDMFunction", "SDMOutput", "MappingResult", "dynamic_flow", "explain_point",
           "WINDOW_OFFSETS"]
