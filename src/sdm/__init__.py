"""Spatial Domain Mapping (SDM): a differentiable PyTorch layer and the Sky experiments.

Public API (everything else is reachable through the submodules):

* geometry: :class:`Camera`, :data:`APOLLO_CAMERA_5`
* data: :func:`build_configuration`, :class:`SkyConfiguration`, :data:`SKY_SHIFT`,
  :func:`add_target_noise`, :func:`noise_displacement`, :class:`ConfigurationSet`
* the layer: :class:`SpatialDomainMapping`; its gradient rules: :class:`Rule`, registered by name in
  :data:`RULES`; :data:`FLOW_RULES` the ones a table uses (the experiments measured beside them:
  :data:`sdm.mapping.research_rules.RESEARCH_RULES`)
* training: :class:`TrainSettings`, :func:`train`, :class:`History`; many runs as one program:
  :func:`train_runs`, :class:`RunsHistory`
* metrics: :func:`distance`, :func:`dev_loss`
* errors: :class:`SDMInputError`
"""
from .batch import ConfigurationSet, PointBatch
from .camera import APOLLO_CAMERA_5, Camera
from .errors import SDMInputError
from .mapping import SpatialDomainMapping
from .mapping.rules import FLOW_RULES, RULES, Rule
from .metrics import dev_loss, distance
from .sky import SKY_SHIFT, SkyConfiguration, add_target_noise, build_configuration, noise_displacement
from .train import History, RunsHistory, TrainSettings, train, train_runs

__version__ = "0.1.0"

__all__ = [
    "APOLLO_CAMERA_5", "Camera", "FLOW_RULES", "ConfigurationSet", "History", "PointBatch", "SDMInputError", "SKY_SHIFT",
    "RULES", "Rule", "RunsHistory", "SkyConfiguration", "SpatialDomainMapping", "TrainSettings", "add_target_noise",
    "build_configuration", "dev_loss", "distance", "noise_displacement", "train", "train_runs",
]
