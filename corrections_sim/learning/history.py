"""The past a learner reads again: a :class:`PriorEntry` first, then each correction (a
:class:`CorrectionEntry` for a particle or exact learner, a :class:`ShownEntry` for one that may
learn a feature). Plain values; the families that keep a history hold it in their state.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True, eq=False)
class PriorEntry:
    """The first entry of a belief's history: the prior N(θ̂⁰, P⁰) the past is read from."""

    theta: np.ndarray
    cov: np.ndarray


@dataclass(frozen=True, eq=False)
class CorrectionEntry:
    """A correction as a particle or exact learner reads it again: its environment Eᵗ,
    the robot's trajectory ξᵗ (T, 7), the features Φ_h (k,) and the observation noise N
    (k, k) it was seen under."""

    env: Any
    robot: np.ndarray
    phi_h: np.ndarray
    noise: np.ndarray


@dataclass(frozen=True, eq=False)
class ShownEntry:
    """A correction kept for feature expansion: its environment Eᵗ, the robot's trajectory
    ξᵗ and the person's ξ_h (both (T, 7)), to be read again over a learnt feature."""

    env: Any
    robot: np.ndarray
    corrected: np.ndarray


#: What a belief's history holds: a :class:`PriorEntry` first, then corrections.
HistoryEntry = PriorEntry | CorrectionEntry | ShownEntry


def checked(history, field: str) -> tuple[HistoryEntry, ...]:
    """``history`` as a tuple, the prior first and corrections after it.

    Raises:
        ValueError: naming ``field``, where that order is broken.
    """
    history = tuple(history)
    if history and not isinstance(history[0], PriorEntry):
        raise ValueError(f"{field}: its first entry must be the PriorEntry")
    if any(not isinstance(e, CorrectionEntry | ShownEntry) for e in history[1:]):
        raise ValueError(f"{field}: after the prior, CorrectionEntry or ShownEntry only")
    return history
