"""Spatial Domain Mapping: the layer, its two implementations, the gradient rules and a single-point explainer."""
from . import research_rules  # noqa: F401 (registers the experiments in RULES)
from .explain import explain_point
from .flow import WINDOW_OFFSETS, dynamic_flow
from .layer import SDMFunction, SDMOutput, SpatialDomainMapping
from .result import MappingResult
from .rules import RULES, KernelFlow, Rule

__all__ = ["SpatialDomainMapping", "SDMFunction", "SDMOutput", "MappingResult", "dynamic_flow", "explain_point",
           "WINDOW_OFFSETS", "Rule", "RULES", "KernelFlow"]
