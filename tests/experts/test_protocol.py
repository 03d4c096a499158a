"""Every registered expert (built-in and installed plugins) follows the expert protocol: shapes,
activated ranges, a deterministic ``frame(t)``, gradients reaching the trained tensors, checkpoints that
round-trip (``helpers.protocol``)."""

from __future__ import annotations

import pytest
from helpers.protocol import check_protocol

from moegs.experts import list_experts


@pytest.mark.parametrize("name", [s.name for s in list_experts() if not s.composite])
def test_expert_follows_the_protocol(name, tmp_path):
    check_protocol(name, tmp_path)
