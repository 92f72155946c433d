"""Checks of a learner's own parameters, shared by the families: a positive number, a
fraction, an integer of at least a bound, and a maths class's field re-raised under the
learner's parameter name.
"""

from __future__ import annotations

import math

from corrections_sim.components import ParameterError


def require_positive(name: str, value) -> None:
    ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
    if not (ok and value > 0):
        raise ParameterError(name, f"must be a finite number > 0, got {value!r}")


def require_fraction(name: str, value) -> float:
    """Refuse a parameter that is not a number in (0, 1); the number as a float."""
    ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
    if not (ok and 0.0 < value < 1.0):
        raise ParameterError(name, f"must lie in (0, 1), got {value!r}")
    return float(value)


def require_count(name: str, value, low: int) -> None:
    """Refuse a parameter that is not an integer >= ``low``."""
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise ParameterError(name, f"must be an integer >= {low}, got {value!r}")


def renamed_keys(build, names: dict[str, str]):
    """``build()``, with a ValueError that names a field of the maths' own class (``a_min``)
    re-raised under the learner's parameter name (``attenuation_min``)."""
    try:
        return build()
    except ValueError as exc:
        message = str(exc)
        for old, new in names.items():
            if message.startswith(old + ":"):
                raise ParameterError(new, message[len(old) + 1 :].strip()) from None
        raise
