"""The example registry (`cstorm.examples`): names, lookup, unknown names refused."""

from __future__ import annotations

import pytest

import cstorm as cs
from cstorm import examples


def test_registry():
    assert "acrobot" in examples.names()
    assert examples.get("acrobot") is examples.acrobot
    with pytest.raises(cs.InputError, match="unknown example"):
        examples.get("nope")
