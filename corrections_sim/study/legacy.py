"""Study files written before components owned their parameters: their flat keys
(``user_step``, ``correction_model``, ``attenuation_min``, ``n_starts``, …) translated to where
they go now (:data:`LEGACY_KEYS`, :func:`translate_legacy`), and a recorded summary's settings
brought to today's form (:func:`normalize_recorded`)."""

from __future__ import annotations

import json
import math
import warnings
from collections.abc import Mapping
from typing import Any

from corrections_sim import components
from corrections_sim.learning.base import make_learner
from corrections_sim.people.corrections import CORRECTIONS
from corrections_sim.people.users import USERS, make_user
from corrections_sim.study.files import as_table
from corrections_sim.study.settings import DEFAULT_LEARNERS, PLANNER_SETTINGS, FilterSettings

#: Flat keys of study files written before components owned their parameters -> where they go
#: now: ("filter" | "planner" | "user", parameter), or ("learners", (learners…), parameter)
#: for the built-in learners that read them. A learner key applies to those of the named
#: learners the study runs. ``user_params``/``learner_params`` are whole tables.
LEGACY_KEYS: dict[str, tuple] = {
    "process_noise": ("filter", "process_noise"),
    "observation_noise": ("filter", "observation_noise"),
    "sigma_alpha": ("filter", "sigma_alpha"),
    "sigma_beta": ("filter", "sigma_beta"),
    "sigma_kappa": ("filter", "sigma_kappa"),
    "n_starts": ("planner", "n_starts"),
    "solver": ("planner", "solver"),
    "user_step": ("user", "step"),
    "user_waypoints": ("user", "waypoints"),
    "user_params": ("user", None),
    "learner_params": ("learners", None, None),
    "fixed_alpha": ("learners", ("PP", "PP-C"), "fixed_alpha"),
    "ekf_step": ("learners", ("EKF",), "step"),
    "attenuation_min": ("learners", ("KF-A",), "attenuation_min"),
    "attenuation_max": ("learners", ("KF-A",), "attenuation_max"),
    "attenuation_points": ("learners", ("KF-A",), "attenuation_points"),
    "beta_min": ("learners", ("BP",), "beta_min"),
    "beta_max": ("learners", ("BP",), "beta_max"),
    "beta_points": ("learners", ("BP",), "beta_points"),
    "lapse": ("learners", ("BP",), "lapse"),
    "correction_model": ("learners", ("KF-C", "AL-C"), "model"),
    "correction_step": ("learners", ("KF-C", "AL-C"), "model"),
    "correction_waypoints": ("learners", ("KF-C", "AL-C"), "model"),
}


#: The old flat keys' defaults: a legacy key at its old default is dropped where its target
#: does not take it or does not run (an old summary recorded them all, whichever user or
#: learners ran); at another value it is refused there, since it would change nothing.
_LEGACY_DEFAULTS = {
    "user_step": 1.0,
    "user_waypoints": 1,
    "correction_model": "waypoint",
    "correction_step": 1.0,
    "correction_waypoints": 1,
    "fixed_alpha": None,
    "ekf_step": 0.05,
    "attenuation_min": 0.05,
    "attenuation_max": 1.0,
    "attenuation_points": 12,
    "beta_min": 0.3,
    "beta_max": 30.0,
    "beta_points": 15,
    "lapse": 0.0,
}


def translate_legacy(values: dict) -> dict:
    """``values`` with the flat keys of :data:`LEGACY_KEYS` moved to their places (an explicit
    nested value wins over a flat one).

    Raises:
        ValueError: a flat key that fits nowhere, named (``user_step = 0.5: the noisy user
            has no parameter step``).
    """
    values = dict(values)
    legacy = {k: values.pop(k) for k in list(values) if k in LEGACY_KEYS}
    if not legacy:
        return values
    for group in ("filter", "planner"):
        given = {LEGACY_KEYS[k][1]: v for k, v in legacy.items() if LEGACY_KEYS[k][0] == group}
        if given:
            values[group] = {**given, **as_table(values.get(group), group)}
    user = values.get("user", "biased")
    user = {"name": user} if isinstance(user, str) else as_table(user, "user")
    name = user.get("name", "biased")
    taken = components.defaults(USERS[name]) if name in USERS else {}
    extra = dict(as_table(legacy.get("user_params"), "user_params"))
    for key in ("user_step", "user_waypoints"):
        if key not in legacy or legacy[key] is None:
            continue
        param = LEGACY_KEYS[key][1]
        if param in taken:
            extra.setdefault(param, legacy[key])
        elif legacy[key] != _LEGACY_DEFAULTS[key]:
            raise ValueError(f"{key} = {legacy[key]!r}: the {name} user has no parameter {param}")
    if name == "noisy" and "observation_noise" in legacy and "noise" not in extra:
        # Before users owned their parameters, the noisy user's σ was √N of the filters.
        extra["noise"] = math.sqrt(float(legacy["observation_noise"]))
    if extra:
        values["user"] = {**user, **{k: v for k, v in extra.items() if k not in user}}
    learners = values.get("learners", list(DEFAULT_LEARNERS))
    table = (
        {n: {} for n in learners}
        if isinstance(learners, list | tuple)
        else {
            n: dict(as_table(p, f"learners.{n}")) for n, p in as_table(learners, "learners").items()
        }
    )
    for name, params in as_table(legacy.get("learner_params"), "learner_params").items():
        if name not in table:
            raise ValueError(f"learner_params: {name!r} is not one of the learners")
        table[name] = {**as_table(params, f"learner_params.{name}"), **table[name]}
    model = legacy.get("correction_model")
    for key, value in legacy.items():
        target = LEGACY_KEYS[key]
        if target[0] != "learners" or target[1] is None or value is None:
            continue
        if not any(n in table for n in target[1]) and value != _LEGACY_DEFAULTS[key]:
            raise ValueError(
                f"{key} = {value!r}: it sets {' and '.join(target[1])}, which the study does not "
                f"run (learners: {', '.join(table)})"
            )
        for learner in target[1]:
            if learner not in table:
                continue
            params = table[learner]
            if target[2] == "model":
                spec = params.get("model", {"name": model or "waypoint"})
                spec = {"name": spec} if isinstance(spec, str) else dict(spec)
                if key == "correction_model":
                    spec["name"] = spec.get("name", value) if "model" in params else value
                else:
                    param = key.removeprefix("correction_")
                    kind = spec.get("name", "waypoint")
                    if param in components.defaults(CORRECTIONS[kind]):
                        spec.setdefault(param, value)
                    elif value != _LEGACY_DEFAULTS[key]:
                        raise ValueError(
                            f"{key} = {value!r}: the {kind} correction model has no {param}"
                        )
                params["model"] = spec
            else:
                params.setdefault(target[2], value)
    values["learners"] = table
    return values


class OlderSpelling(UserWarning):
    """A study file in the flat keys of :data:`LEGACY_KEYS`: read as before, with a one-line
    note of the nested spelling (the command line prints it as ``note: …``)."""


def note_older_spellings(values: Mapping[str, Any], where: str) -> None:
    """Warn (:class:`OlderSpelling`) once per flat key of ``values`` (a file's, at ``where``)
    with the spelling a study file takes now."""
    for key, value in values.items():
        if key not in LEGACY_KEYS:
            continue
        target = LEGACY_KEYS[key]
        shown = json.dumps(value) if isinstance(value, str | int | float) else str(value)
        if target[0] == "learners" and target[1] is None:
            new = "a [learners.NAME] table per learner"
        elif target[0] == "learners":
            runs = [n for n in target[1] if n in values.get("learners", DEFAULT_LEARNERS)]
            value = shown
            if key in ("correction_step", "correction_waypoints"):
                value = f"{{ {key.removeprefix('correction_')} = {shown} }}"
            new = " and ".join(f"[learners.{n}] {target[2]} = {value}" for n in runs or target[1])
        elif target[1] is None:
            new = f"a [{target[0]}] table"
        else:
            new = f"[{target[0]}] {target[1]} = {shown}"
        warnings.warn(
            f"{where}: {key} = {shown} is an older spelling; write {new} (docs/study-files.md)",
            OlderSpelling,
            stacklevel=2,
        )


def current_learner_params(name: str, params: Any) -> Any:
    """A recorded learner's parameters (a summary's, a session log's) in today's form: without
    those it gave up where they did nothing (KF-CRP's ``expand_*`` went to KF-CRX, issue 64;
    with ``expand_traces = 0`` it never asked), KF-CRX's one ``expand_variance`` as the
    one candidate of ``expand_variances``, and a KF-CRX recorded before its learnt feature's
    noise was fitted as the choice among one share, the study's noise (both issue 69)."""
    if name == "KF-CRP" and isinstance(params, dict) and params.get("expand_traces", 0) == 0:
        return {k: v for k, v in params.items() if not k.startswith("expand_")}
    if name == "KF-CRX" and isinstance(params, dict):
        if "expand_variance" in params:
            # One prior variance for a learnt weight became a choice among several (issue
            # 69): the older setting is that choice with one candidate.
            kept = {k: v for k, v in params.items() if k != "expand_variance"}
            params = kept | {"expand_variances": [params["expand_variance"]]}
        if "expand_noises" not in params:
            # Its learnt feature's noise was the study's until it was fitted (issue 69).
            params = params | {"expand_noises": [1.0]}
    return params


def normalize_recorded(settings: Mapping[str, Any]) -> dict:
    """Settings recorded in an older ``summary.json`` (flat keys) in today's nested form, so an
    output folder made before components owned their parameters compares equal when its
    settings are. Anything that does not translate is returned as it was."""
    try:
        values = translate_legacy(dict(settings))
    except (ValueError, KeyError, TypeError):
        return dict(settings)
    if isinstance(values.get("user"), str):
        values["user"] = {"name": values["user"]}
    user = values.get("user")
    if isinstance(user, dict) and user.get("name") in USERS:
        try:
            built = make_user(user["name"], {k: v for k, v in user.items() if k != "name"})
            values["user"] = {"name": user["name"], **components.params(built)}
        except ValueError:
            pass
    learners = values.get("learners")
    if isinstance(learners, dict):
        out = {}
        for name, params in learners.items():
            params = current_learner_params(name, params)
            try:
                out[name] = components.params(make_learner(name, params))
            except (ValueError, KeyError):
                out[name] = params
        values["learners"] = out
    planner = values.get("planner")
    if isinstance(planner, dict):
        values["planner"] = {**PLANNER_SETTINGS, **planner}
    if isinstance(values.get("filter"), dict):
        values["filter"] = components.params(FilterSettings(**values["filter"]))
    return values
