"""Densification strategies (dataclass of hyperparameters + explicit state, gsplat style)."""

from moegs.train.strategy.adc import ADCStrategy
from moegs.train.strategy.base import NEVER, Strategy
from moegs.train.strategy.mcmc import MCMCStrategy

__all__ = ["NEVER", "ADCStrategy", "MCMCStrategy", "Strategy"]
