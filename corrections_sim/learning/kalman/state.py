"""The Kalman family's part of a belief for a filter that learns the observation noise N
(KF-CL, AL-CL): the inverse-Wishart posterior over N (:class:`NoiseState`). Plain values.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from corrections_sim.belief import FamilyState, _as_symmetric, _check_positive_definite, frozen


@dataclass(frozen=True, eq=False)
class NoisePosterior:
    """A belief over the observation noise N: inverse-Wishart IW(ν, V), density
    ∝ |N|^(−(ν + k + 1)/2) exp(−tr(V N⁻¹)/2).

    Under it E[N⁻¹] = ν V⁻¹, so the noise a variational-Bayes filter plugs into its update
    is N̂ = E[N⁻¹]⁻¹ = V / ν (:meth:`estimate`).

    Attributes:
        dof: ν > k − 1, the degrees of freedom: how many corrections' worth of evidence.
        scale: V, shape (k, k), symmetric positive definite.
    """

    dof: float
    scale: np.ndarray

    def __post_init__(self) -> None:
        scale = _as_symmetric("NoisePosterior.scale", self.scale)
        _check_positive_definite("NoisePosterior.scale", scale)
        k = scale.shape[0]
        if not (np.isfinite(self.dof) and self.dof > k - 1):
            raise ValueError(f"NoisePosterior.dof: must be finite and > {k - 1}, got {self.dof}")
        object.__setattr__(self, "dof", float(self.dof))
        object.__setattr__(self, "scale", frozen(scale))

    @classmethod
    def around(cls, noise: np.ndarray, dof: float) -> NoisePosterior:
        """A prior whose estimate is ``noise`` (k, k), held with ``dof`` degrees of freedom."""
        return cls(dof=dof, scale=dof * np.asarray(noise, dtype=float))

    @property
    def dim(self) -> int:
        return int(self.scale.shape[0])

    def estimate(self) -> np.ndarray:
        """N̂ = V / ν, shape (k, k)."""
        return self.scale / self.dof


@dataclass(frozen=True, eq=False)
class NoiseState(FamilyState):
    """A noise-learning filter's own state: its posterior over N."""

    noise: NoisePosterior

    def check(self, k: int) -> None:
        check_noise(self.noise, k, "NoiseState.noise")

    def columns(self) -> dict[str, float]:
        return noise_columns(self.noise)

    def noise_estimate(self) -> np.ndarray | None:
        return self.noise.estimate()


def check_noise(noise: NoisePosterior | None, k: int, field: str) -> None:
    """Raise ``ValueError`` naming ``field`` if ``noise`` is not a posterior over k x k N."""
    if noise is not None and noise.dim != k:
        raise ValueError(
            f"{field}: a posterior over {noise.dim} x {noise.dim} noise, expected {k} x {k}"
        )


def noise_columns(noise: NoisePosterior | None) -> dict[str, float]:
    """N̂'s upper triangle, ``noise_ij`` (i ≤ j); none without a posterior over N."""
    if noise is None:
        return {}
    estimate, k = noise.estimate(), noise.dim
    return {f"noise_{i}{j}": float(estimate[i, j]) for i in range(k) for j in range(i, k)}
