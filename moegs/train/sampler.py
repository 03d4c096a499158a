"""Training-view order: shuffled stacks per view group, refilled when empty (3DGS ``viewpoint_stack``)."""

from __future__ import annotations

import torch


class ViewSampler:
    """Draws ``batch_size`` view indices from every group per step, without replacement within an
    epoch of the group.

    Args:
        groups: group index of each view (all zeros for one group).
        batch_size: views per group per step.
        seed: seed of the sampler's own generator.
    """

    def __init__(self, groups: list[int], batch_size: int, seed: int) -> None:
        if not groups:
            raise ValueError("ViewSampler needs at least one view")
        self.batch_size = batch_size
        self.members: dict[int, list[int]] = {}
        for index, group in enumerate(groups):
            self.members.setdefault(int(group), []).append(index)
        self.generator = torch.Generator(device="cpu").manual_seed(seed)
        self.stacks: dict[int, list[int]] = {g: [] for g in self.members}
        self.left = 0
        """Views the first group's stack held before the last batch's first draw (refilled when empty):
        the ``len(viewpoint_stack)`` of the originals' loops, which shrinks through an epoch."""

    def next(self) -> list[int]:
        """View indices of the next batch, group by group."""
        batch = []
        for group in sorted(self.members):
            for _ in range(self.batch_size):
                if not self.stacks[group]:
                    order = torch.randperm(
                        len(self.members[group]), generator=self.generator, device="cpu"
                    ).tolist()
                    self.stacks[group] = [self.members[group][i] for i in order]
                if not batch:
                    self.left = len(self.stacks[group])
                batch.append(self.stacks[group].pop())
        return batch

    def state_dict(self) -> dict:
        return {
            "generator": self.generator.get_state(),
            "stacks": {g: list(s) for g, s in self.stacks.items()},
        }

    def load_state_dict(self, state: dict) -> None:
        if set(state["stacks"]) != set(self.stacks):
            raise ValueError(
                f"sampler state has view groups {sorted(state['stacks'])}, expected {sorted(self.stacks)}"
            )
        self.generator.set_state(state["generator"])
        self.stacks = {int(g): list(s) for g, s in state["stacks"].items()}
