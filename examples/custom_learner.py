"""A custom learner, written only against the public API: a normalized perceptron.

θ̂ᵗ⁺¹ = θ̂ᵗ + α (Φ_h − Φ(ξᵗ)) / max(‖Φ_h − Φ(ξᵗ)‖, ε): the perceptron's direction with a step
of fixed length α, so that a large correction does not throw the estimate far. It keeps P⁰
(no covariance), chooses environments at random like the paper's PP, and needs no Kalman
gains. Registering it is the one line ``@register_learner("NPP")``; after that a study
names it like any of the paper's learners (``learners = ["KF", "NPP"]``) and passes its
parameter as ``learner_params = {"NPP": {"step": 0.2}}``.

Run: ``python examples/custom_learner.py`` (a tiny study; prints JSON).
"""

from __future__ import annotations

import json

import numpy as np

from corrections_sim.learning import Belief
from corrections_sim.learning.base import Learner, Step, register_learner


@register_learner("NPP")
class NormalizedPerceptron(Learner):
    """Preference perceptron with a step of fixed length ``step`` in θ."""

    label = "Normalized perceptron (NPP)"
    has_covariance = False

    def __init__(self, step: float = 0.25) -> None:
        if not (isinstance(step, int | float) and np.isfinite(step) and step > 0):
            raise ValueError(f"step = {step!r} must be finite and > 0")
        self.step = float(step)

    def update(self, ctx, belief, env, plan, phi_h) -> Step:
        change = phi_h - plan.features
        theta = belief.theta + self.step * change / max(float(np.linalg.norm(change)), 1e-9)
        return Step(Belief(theta=theta, cov=belief.cov), gain=None, innovation=change)


def main(iterations: int = 4, runs: int = 2) -> dict:
    """Runs NPP on four of the paper's environments; the mean estimate error per iteration."""
    from corrections_sim.planning.planner import Planner, PlannerConfig
    from corrections_sim.scene.environments import paper_environments
    from corrections_sim.study.loop import StudySettings, Target, run_learner

    settings = StudySettings(
        theta_star=(1.0, -1.0),
        theta0=(0.0, 0.0),
        cov0=((1.0, 0.0), (0.0, 1.0)),
        iterations=iterations,
        runs=runs,
        learners=("NPP",),
        learner_params={"NPP": {"step": 0.3}},
    )
    planner = Planner(PlannerConfig(features=("laptop", "table"), n_starts=1))
    envs = paper_environments()[::12]
    target = Target.solve(planner, settings.theta_star, envs)
    errors = []
    for run in range(runs):
        rng = np.random.default_rng([settings.seed, run])
        result = run_learner("NPP", run, settings, planner, envs, target, settings.make_user(), rng)
        errors.append([r["estimate_error"] for r in result.records])
    return {"learner": "NPP", "mean_estimate_error": np.mean(errors, axis=0).tolist()}


if __name__ == "__main__":
    print(json.dumps(main()))
