"""SGFD for Stable-Baselines3: saliency-guided features decorrelation by sample reweighting."""

__version__ = "0.1.0"
