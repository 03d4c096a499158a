"""The one training loop (``moegs.train.loop.train``), its config, strategies, losses, schedules and
checkpoints. Nothing is imported here so that ``moegs.experts.base`` can use ``TrainConfig``."""
