"""Densification strategies (dataclass of hyperparameters + explicit state, gsplat style)."""

from moegs.train.strategy.adc import ADCStrategy
from moegs.train.strategy.base import Strategy
from moegs.train.strategy.mcmc import MCMCStrategy

__all__ = ["ADCStrategy", "MCMCStrategy", "Strategy"]
