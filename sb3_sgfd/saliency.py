"""SGFD's domain classifier and the feature probabilities from its saliency, by the path earlier code imports them
from; they live in :mod:`sb3_sgfd.sgfd.classifier` and :mod:`sb3_sgfd.sgfd.functional`."""

from sb3_sgfd.sgfd.classifier import DomainClassifier
from sb3_sgfd.sgfd.functional import classifier_accuracy, feature_probabilities, saliency_map, train_classifier

__all__ = ["DomainClassifier", "classifier_accuracy", "feature_probabilities", "saliency_map", "train_classifier"]
