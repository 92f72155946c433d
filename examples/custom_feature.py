"""A custom feature, written only against the public API: closeness to a person standing by
the table.

One environment field, ``person_x``/``person_y`` (where the person stands; an environment
sets them through ``extra={...}``, the others take the default), and one function of the
waypoint: exp(−‖c_xy − p_xy‖² / (2 σ²)), σ = 0.2 m, with c the cup's centre. A positive
weight makes the robot carry the coffee past the person, a negative one keeps it away. After
import, ``PlannerConfig(features=("laptop", "table", "person"))`` plans with it and a study
can learn its weight. Register environment parameters at import, before building planners.

Run: ``python examples/custom_feature.py`` (plans with and without the person; prints JSON).
"""

from __future__ import annotations

import json

import casadi as ca

from corrections_sim.planning.features import Waypoint, register_feature
from corrections_sim.scene.environments import ENV_PARAMETERS, register_env_parameter

PERSON_SCALE = 0.2  # m, σ

register_env_parameter("person_x", default=0.55)
register_env_parameter("person_y", default=-0.45)


@register_feature("person")
def person(w: Waypoint) -> ca.SX:
    """exp(−‖c_xy − p_xy‖² / (2 σ²)): the coffee near the person."""
    d2 = (w.cup[0] - w.param("person_x")) ** 2 + (w.cup[1] - w.param("person_y")) ** 2
    return ca.exp(-d2 / (2 * PERSON_SCALE**2))


def main() -> dict:
    """Φ_person of the robot's plan when it ignores, seeks and avoids the person."""
    import dataclasses

    import numpy as np

    from corrections_sim.planning.planner import Planner, PlannerConfig
    from corrections_sim.scene.environments import paper_environments

    features = ("laptop", "table", "person")
    # jit=False: no gcc build for a one-off feature set (slower solves, instant start).
    planner = Planner(PlannerConfig(features=features, n_starts=1, jit=False))
    env = dataclasses.replace(paper_environments()[0], extra={"person_x": 0.45, "person_y": 0.0})
    names = list(ENV_PARAMETERS)
    out = {"env_params": dict(zip(names, env.params().tolist(), strict=True))}
    for name, weight in (("ignore", 0.0), ("seek", 2.0), ("avoid", -2.0)):
        plan = planner.solve(np.array([0.0, 0.0, weight]), env)
        out[name] = float(plan.features[features.index("person")])
    return out


if __name__ == "__main__":
    print(json.dumps(main()))
