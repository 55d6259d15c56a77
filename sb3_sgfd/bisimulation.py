"""The behavioural-metric losses of DBC and AMBS, by the path earlier code imports them from; they live in
:mod:`sb3_sgfd.dbc.losses` and :mod:`sb3_sgfd.ambs.losses`."""

from sb3_sgfd.ambs.losses import MetricLearner, ambs_metric_loss, ambs_metric_loss_code
from sb3_sgfd.dbc.losses import bisimulation_loss, bisimulation_loss_code

__all__ = ["MetricLearner", "ambs_metric_loss", "ambs_metric_loss_code", "bisimulation_loss", "bisimulation_loss_code"]
