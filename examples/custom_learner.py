"""A custom learner, written only against the public API: a normalized perceptron.

θ̂ᵗ⁺¹ = θ̂ᵗ + α (Φ_h − Φ(ξᵗ)) / max(‖Φ_h − Φ(ξᵗ)‖, ε): the perceptron's direction with a step
of fixed length α, so that a large correction does not throw the estimate far. It keeps P⁰
(no covariance), chooses environments at random like the paper's PP, and needs no Kalman
gains. It is a frozen dataclass whose field ``step`` is its parameter (default and check in
the class); registering it is the one line ``@register_learner("NPP")``. After that a study
names it like any of the paper's learners (``learners = ["KF", "NPP"]``) and sets its
parameter in its own table (``[learners.NPP] step = 0.2``, or ``--set learners.NPP.step=0.2``).

Run: ``python examples/custom_learner.py`` (a tiny study; prints JSON).
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

from corrections_sim.belief import Belief
from corrections_sim.components import ParameterError
from corrections_sim.learning.base import Learner, Step, make_learner, register_learner


@register_learner("NPP")
@dataclass(frozen=True)
class NormalizedPerceptron(Learner):
    """Preference perceptron with a step of fixed length ``step`` in θ."""

    label = "Normalized perceptron (NPP)"
    has_covariance = False

    step: float = 0.25

    def __post_init__(self) -> None:
        step = self.step
        if isinstance(step, bool) or not (
            isinstance(step, int | float) and np.isfinite(step) and step > 0
        ):
            raise ParameterError("step", f"must be finite and > 0, got {step!r}")

    def update(self, ctx, belief, env, plan, phi_h) -> Step:
        change = phi_h - plan.features
        theta = belief.theta + self.step * change / max(float(np.linalg.norm(change)), 1e-9)
        return Step(Belief(theta=theta, cov=belief.cov), gain=None, innovation=change)


def main(iterations: int = 4, runs: int = 2) -> dict:
    """Runs NPP on four of the paper's environments; the mean estimate error per iteration."""
    from corrections_sim.planning.planner import Planner, PlannerConfig
    from corrections_sim.plans.book import Target
    from corrections_sim.scene.environments import paper_environments
    from corrections_sim.study.loop import run_learner
    from corrections_sim.study.settings import StudySettings

    settings = StudySettings(
        theta_star=(1.0, -1.0),
        theta0=(0.0, 0.0),
        cov0=((1.0, 0.0), (0.0, 1.0)),
        iterations=iterations,
        runs=runs,
        learners={"NPP": make_learner("NPP", {"step": 0.3})},
    )
    planner = Planner(PlannerConfig(features=("laptop", "table"), n_starts=1))
    envs = paper_environments()[::12]
    target = Target.solve(planner, settings.theta_star, envs)
    errors = []
    for run in range(runs):
        rng = np.random.default_rng([settings.seed, run])
        result = run_learner("NPP", run, settings, planner, envs, target, settings.user, rng)
        errors.append([r["estimate_error"] for r in result.records])
    return {"learner": "NPP", "mean_estimate_error": np.mean(errors, axis=0).tolist()}


if __name__ == "__main__":
    print(json.dumps(main()))
