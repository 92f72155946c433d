"""A figure's study made smaller for a benchmark (``--grid``, ``--study-envs``; ``--tiny``
gives both): its plan atlas at fewer points a weight, its first few paper environments."""

from __future__ import annotations

import json

from corrections_sim.scene.environments import paper_environments


def study_overrides(atlas_points: int | None = None, environments: int | None = None) -> dict:
    """Overrides of a figure's study file (``load_settings(..., overrides=...)``): its atlas
    at ``atlas_points`` points a weight, the first ``environments`` paper environments (None:
    the study's own)."""
    found: dict = {}
    if atlas_points is not None:
        found["atlas"] = {"points": int(atlas_points)}
    if environments is not None:
        if not 1 <= environments <= 48:
            raise ValueError(f"--study-envs: 1 to 48 paper environments, got {environments}")
        found["environments"] = [e.name for e in paper_environments()[:environments]]
    return found


def toml_value(value) -> str:
    """A value of :func:`study_overrides` as TOML: a table inline, the rest as JSON spells it
    (numbers, strings and lists of them read the same in TOML)."""
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {toml_value(v)}" for k, v in value.items()) + " }"
    return json.dumps(value)


def set_options(atlas_points: int | None = None, environments: int | None = None) -> list[str]:
    """The same as ``run`` command-line options (``--set KEY=VALUE`` each)."""
    out = []
    for key, value in study_overrides(atlas_points, environments).items():
        out += ["--set", f"{key} = {toml_value(value)}"]
    return out
