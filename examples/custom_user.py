"""A custom simulated user, written only against the public API: a user who sometimes
does not bother.

With probability ``skip`` it leaves the robot's trajectory as it is (a correction that shows
nothing); otherwise it corrects like the paper's user, moving its worst waypoint ``step`` of
the way toward its own plan ξ*(θ*, E). It draws from the run's generator, so it says
``stochastic = True`` (active learners then run as often as the others). Its parameters are
its dataclass fields, checked where they enter (and named in the error:
``user.skip: must lie in [0, 1]``). Registering it is the one line ``@register_user("lazy")``;
a study then says ``user = { name = "lazy", skip = 0.5 }`` (or ``--user lazy --set
user.skip=0.5``). Its own default step, 0.6, is what a study gets unless it sets ``step``.

Run: ``python examples/custom_user.py`` (a tiny study; prints JSON).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from corrections_sim.components import ParameterError
from corrections_sim.people.corrections import waypoint_correction
from corrections_sim.people.users import Situation, User, make_user, register_user


@register_user("lazy")
@dataclass(frozen=True)
class LazyUser(User):
    """Corrects with probability 1 − ``skip``; moves its worst waypoint ``step`` of the way."""

    skip: float = 0.5
    step: float = 0.6
    stochastic: ClassVar[bool] = True

    def __post_init__(self) -> None:
        if not 0.0 <= self.skip <= 1.0:
            raise ParameterError("skip", f"must lie in [0, 1], got {self.skip!r}")
        if not 0.0 < self.step <= 1.0:
            raise ParameterError("step", f"must lie in (0, 1], got {self.step!r}")

    def correct(self, situation: Situation, rng: np.random.Generator) -> np.ndarray:
        if rng.random() < self.skip:
            return np.array(situation.robot, dtype=float)
        return waypoint_correction(situation.robot, situation.intended, self.step)


def main(iterations: int = 4, skip: float = 0.5) -> dict:
    """KF learning from the lazy user on four of the paper's environments."""
    from corrections_sim.learning.base import make_learner
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
        runs=1,
        learners={"KF": make_learner("KF")},
        user=make_user("lazy", {"skip": skip}),
        user_name="lazy",
    )
    planner = Planner(PlannerConfig(features=("laptop", "table"), n_starts=1))
    envs = paper_environments()[::12]
    target = Target.solve(planner, settings.theta_star, envs)
    rng = np.random.default_rng(settings.seed)
    result = run_learner("KF", 0, settings, planner, envs, target, settings.user, rng)
    thetas = [[r["theta_0"], r["theta_1"]] for r in result.records]
    return {
        "user": repr(settings.user),
        "theta": thetas,
        "estimate_error": [r["estimate_error"] for r in result.records],
    }


if __name__ == "__main__":
    print(json.dumps(main()))
