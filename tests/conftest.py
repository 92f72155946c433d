"""Shared pytest fixtures."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture
def rng() -> np.random.Generator:
    """A generator seeded with the paper's conference date, fresh for each test."""
    return np.random.default_rng(20181029)
