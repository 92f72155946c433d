"""Replay a logged session through any learners, offline.

Every learner sees the same corrections in the same environments, in the logged order: at
iteration t it updates on the logged Φ_h of the correction of the logged robot plan ξᵗ (what
the person actually corrected), from its own belief. The records are those of a study
(:func:`corrections_sim.study.loop.run_learner`): θ̂ and P per iteration, and where the person
stated a preference θ, the estimate error, regret and NEES against it; one run per learner.

A PP-type learner whose rate comes from another learner's gains gets them from that learner
replayed on the same corrections (added to the replay if it was not asked for). The session's
own learner replayed gives back the logged θ̂ (checked: ``max_gap_to_log``): exactly on the
machine that logged a session planned from cold starts (every plan a pure function of (θ, E)),
within :data:`~corrections_sim.session.session.LOG_TOLERANCE` on another processor, and at the
solver's tolerance for a session planned warm (the replay plans cold); a session planned from
a plan atlas is replayed from the same atlas. The summary says whether the machine is the one
that logged the session (``same_machine``) and whether the atlas is the session's
(``same_atlas``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence

import numpy as np

from corrections_sim import components, provenance
from corrections_sim.defaults import DEFAULTS
from corrections_sim.learning import correction
from corrections_sim.learning.base import LEARNERS
from corrections_sim.learning.perceptron.update import learning_rate_schedule
from corrections_sim.metrics import estimate_error, label_scores
from corrections_sim.planning.features import feature_counts
from corrections_sim.planning.planner import Plan, PlanningError, shared_planner
from corrections_sim.plans.book import PlanBook, Target, evaluate
from corrections_sim.session.log import StudyLog
from corrections_sim.session.session import (
    LOG_TOLERANCE,
    build_learner,
    learner_rng,
    settings_from_log,
)
from corrections_sim.session.teaching import teach_rng
from corrections_sim.study.loop import belief_columns
from corrections_sim.study.runner import FigureResult
from corrections_sim.study.settings import FigureSettings

#: Learners a replay runs when none are named (plus the session's own).
DEFAULT_LEARNERS = DEFAULTS["replay"]


def logged_plan(row: dict, features: np.ndarray | None = None) -> Plan:
    """The robot's plan ξᵗ as the session showed it (with ``features``: Φ(ξᵗ) over another
    learner's features than the session's)."""
    return Plan(
        trajectory=row["xi_robot"],
        features=row["phi_robot"] if features is None else features,
        reward=float("nan"),
        status="logged",
        iterations=0,
        solve_time=0.0,
        starts=0,
    )


def replay(
    log: StudyLog,
    session_id: int,
    learners: Sequence[str] | None = None,
    *,
    regret: bool = True,
    params: Mapping[str, Mapping] | None = None,
) -> tuple[FigureSettings, FigureResult, dict]:
    """(settings of the replay, its records as a study's result, facts for the summary).

    Args:
        learners: registered learner names (default :data:`DEFAULT_LEARNERS` and the
            session's own).
        regret: evaluate the regret against the stated θ (48 solves per learner and
            iteration for the paper's environments); without a stated θ there is none.
        params: per learner name, parameters that replace those it would have (the
            session's own learner's logged ones, else the study's, else its defaults), e.g.
            ``{"KF-CR": {"model": "physical"}}``: a physical session replayed through
            learners told that people push.

    Raises:
        LogError: no such session.
        ValueError: an unknown learner, or a session without corrections.
    """
    row = log.session(session_id)
    rows = log.corrections(session_id)
    if not rows:
        raise ValueError(f"session {session_id}: no corrections to replay")
    settings = settings_from_log(row.settings)
    names = list(learners) if learners else [*DEFAULT_LEARNERS, row.learner]
    params = dict(params or {})
    for name in [*names, *params]:
        if name not in LEARNERS:
            raise ValueError(f"learner {name!r}: unknown; choose from {', '.join(LEARNERS)}")
    # A learner that reads the study's plan atlas cannot replay a session whose study had
    # none: left out of the defaults (said in the facts), refused when named.
    left_out = []
    if settings.atlas_spec() is None:
        left_out = [n for n in dict.fromkeys(names) if LEARNERS[n].needs_atlas]
        if learners and left_out:
            raise ValueError(
                f"--learners {left_out[0]}: needs the study's plan atlas, and session "
                f"{session_id}'s study had none (replay it through the others)"
            )
        names = [n for n in names if n not in left_out]
    for name in params:
        if name not in names:
            raise ValueError(f"learners.{name}: set, but not replayed (--learners)")
    # Each rate source before the learner that needs it (added if not asked for); the
    # session's own learner with its logged parameters, the others with the study's.
    agents: dict = {}

    def add(name: str) -> None:
        if name not in agents:
            given = row.learner_params if name == row.learner else None
            if name in params:
                if given is None and name in settings.study.learners:
                    given = components.params(settings.study.learners[name])
                given = {**(given or {}), **params[name]}
            agent = build_learner(settings, name, given)
            if agent.rate_source() is not None:
                add(agent.rate_source())
            agents[name] = agent

    for name in names:
        add(name)
    order = list(agents)

    stated = row.stated_theta
    labels = log.labels(session_id)
    teaching = _teaching(log, session_id)
    s = settings.study
    planner = shared_planner(settings.planner_config())
    envs = settings.envs()
    book = PlanBook(planner, atlas=settings.atlas())  # as the session planned
    target = Target.solve(planner, stated, envs) if stated is not None and regret else None
    records: list[dict] = []
    gains_of: dict[str, np.ndarray] = {}
    alphas_of: dict[str, list[float]] = {}
    gap_to_log = None
    k, n = s.k, len(rows)
    for name in order:
        agent, cls = agents[name], LEARNERS[name]
        alphas = None
        if cls.needs_rates():
            if agent.fixed_rate() is not None:
                alphas = np.full(n, agent.fixed_rate())
            else:
                gains = gains_of[agent.rate_source()]
                alphas = learning_rate_schedule(np.nan_to_num(gains[None], nan=0.0))
            alphas_of[name] = [float(a) for a in alphas]
        belief = agent.initial(s.prior(), s.noise())
        gains = np.full((n, k, k), np.nan)
        books = {settings.features: book}

        def record(t, env_name, skipped, step, belief, name=name, cls=cls, books=books):
            rec = {"learner": name, "run": 0, "iteration": t, "environment": env_name}
            if stated is not None:
                rec["estimate_error"] = estimate_error(belief.theta[:k], stated)
                if target is not None:
                    mine = _book(books, settings, belief)
                    full, paper, failed = evaluate(mine, target, envs, belief.theta)
                    rec |= {"regret": full, "regret_paper": paper, "regret_failures": failed}
            rec["update_skipped"] = skipped
            # The learnt features' names, in the order of θ̂'s entries after the study's.
            rec["learnt_features"] = ";".join(belief.extra)
            rec |= belief_columns(belief, step, stated, cls.has_covariance)
            if t > 0 and (t - 1) in labels:  # what the person was asked for
                rec["relevant"] = float(labels[t - 1]["label"])
            records.append(rec)

        record(0, "", "", None, belief)
        for t, logged in enumerate(rows):
            env = envs[int(logged["env_index"])]
            current = settings.features + tuple(belief.extra)
            if belief.extra:  # Φ over the features this learner has learnt too
                phi_h = feature_counts(logged["xi_h"], env, current)
                plan = logged_plan(logged, feature_counts(logged["xi_robot"], env, current))
            else:
                phi_h = np.asarray(logged["phi_h"])[:k]
                plan = logged_plan(logged, np.asarray(logged["phi_robot"])[:k])
            ctx = correction.context(
                belief,
                s.noise(),
                book=_book(books, settings, belief),
                envs=envs,
                features=current,
                n_waypoints=planner.config.n_waypoints,
                alphas=alphas,
                rng=learner_rng(row.seed, t),
                sigma=s.sigma(),
                iteration=t,
                corrected=logged["xi_h"],
            )
            skipped, step = "", None
            try:
                step = correction.step(agent, ctx, belief, env, plan, phi_h)
                belief = step.belief
                if step.gain is not None:
                    gains[t] = step.gain[:k, :k]
            except PlanningError as exc:
                skipped = str(exc).splitlines()[0]
            belief = _teach(agent, belief, t + 1, teaching, envs, row.seed, ctx)
            record(t + 1, env.name, skipped, step, belief)
            if name == row.learner and belief.theta.shape == logged["theta_after"].shape:
                gap = float(np.max(np.abs(belief.theta - logged["theta_after"])))
                gap_to_log = gap if gap_to_log is None else max(gap_to_log, gap)
        gains_of[name] = gains

    study = dataclasses.replace(
        s,
        theta_star=tuple(float(v) for v in (stated if stated is not None else s.theta_star)),
        iterations=n,
        runs=1,
        learners={name: agents[name] for name in order},
    )
    replayed = dataclasses.replace(settings, study=study, name=f"session-{session_id}")
    result = FigureResult(
        records=records, mean_estimate=[], alphas=alphas_of, solves=book.solves, resumed=0
    )
    facts = {
        "session": session_id,
        "participant": row.participant,
        "session_learner": row.learner,
        "left_out": left_out,
        "corrector": row.corrector,
        "correction_model": row.correction,
        "corrections": n,
        "stated_theta": None if stated is None else stated.tolist(),
        "max_gap_to_log": gap_to_log,
        "log_tolerance": LOG_TOLERANCE,
        "same_machine": same_machine(log, session_id),
        "same_atlas": same_atlas(log, session_id, settings),
        "labelled": labelled_scores(records, order),
        "learnt_features": learnt_features(log, session_id, settings, records, row.learner),
        "final": {
            name: {
                "theta": [r[f"theta_{i}"] for i in range(k)],
                "learnt": [r.get(f"theta_{i}") for i in range(k, k + 4) if f"theta_{i}" in r],
                "estimate_error": r.get("estimate_error"),
            }
            for name in order
            for r in [next(r for r in reversed(records) if r["learner"] == name)]
        },
    }
    return replayed, result, facts


def learnt_features(
    log: StudyLog, session_id: int, settings: FigureSettings, records: Sequence[dict], learner: str
) -> list[dict]:
    """Each feature the session learnt: its name, after how many corrections, from how many
    traces, in which environment; its weight as the session logged it last and the replayed
    session learner's final weight with its sd; and
    where the log names the person's truth (a ``truth`` event: a scripted person's features
    and weights), its quality against each true feature the study lacks
    (:func:`~corrections_sim.learnt.training.quality`: Spearman's ρ and R², FERL's measure)."""
    from corrections_sim.learnt.training import quality, register_logged

    truth = log.events(session_id, "truth")
    truths = []
    if truth:
        detail = truth[0]["detail"]
        truths = [
            f
            for f, w in zip(detail["features"], detail["theta"], strict=True)
            if w != 0 and f not in settings.features
        ]
    last = next((r for r in reversed(records) if r["learner"] == learner), None)
    k = settings.study.k
    envs = settings.envs()
    # The session's own weights, as logged last (a replay that plans cold may differ).
    logged = log.corrections(session_id)[-1]["theta_after"]
    out = []
    for i, event in enumerate(log.events(session_id, "learnt")):
        detail = event["detail"]
        entry = {
            "feature": detail["feature"],
            "after": int(event["iteration"]),
            "traces": int(detail["traces"]),
            "env_index": int(detail["env_index"]),
            "weight": None,
            "sd": None,
        }
        j = k + i
        entry["logged_weight"] = float(logged[j]) if len(logged) > j else None
        if last is not None and f"theta_{j}" in last:
            entry["weight"] = last[f"theta_{j}"]
            cov = last.get(f"cov_{j}{j}")
            entry["sd"] = None if cov is None else float(np.sqrt(max(cov, 0.0)))
        env = envs[entry["env_index"]]
        entry["quality"] = {}
        name = register_logged(detail) if truths else None
        for true in truths:
            q = quality(name, true, env)
            entry["quality"][true] = {"spearman": q.spearman, "r2": q.r2, "n": q.n}
        out.append(entry)
    return out


def _teaching(log: StudyLog, session_id: int) -> dict[int, dict]:
    """After how many corrections the person gave feature traces: the traces, and the
    feature learnt from them (or that they declined)."""
    out: dict[int, dict] = {}
    for event in log.events(session_id):
        kind, detail = event["kind"], event["detail"]
        if kind not in ("trace", "traces", "learnt"):
            continue
        at = out.setdefault(int(event["iteration"]), {"traces": []})
        if kind == "trace":
            at["traces"].append(np.asarray(detail["states"], float))
        elif kind == "traces":
            at["declined"] = bool(detail.get("declined"))
        else:
            at["learnt"] = detail
    return out


def _teach(agent, belief, corrections: int, teaching: dict, envs, seed: int, ctx):
    """A learner that asks for traces after ``corrections`` corrections gets the session's:
    it learns the feature from them as the session did (the same seed; the session's own
    learner gives back the logged weights); where the person gave none it is told so."""
    if not agent.learns_features() or not agent.wants_traces(belief, corrections):
        return belief
    given = teaching.get(corrections)
    if given is None or "learnt" not in given:
        return agent.declined(belief)
    env = envs[int(given["learnt"]["env_index"])]
    grown, _ = agent.grow(belief, env, given["traces"], teach_rng(seed, corrections), ctx)
    return grown


def _book(books: dict, settings: FigureSettings, belief) -> PlanBook:
    """The replay's book over the features ``belief`` has (the study's and any learnt)."""
    mine = settings.features + tuple(belief.extra)
    if mine not in books:
        config = dataclasses.replace(settings.planner_config(), features=mine)
        atlas = settings.atlas() if mine == settings.features else None
        books[mine] = PlanBook(shared_planner(config), atlas=atlas)
    return books[mine]


def labelled_scores(records: Sequence[dict], learners: Sequence[str]) -> dict:
    """Per relevance-aware learner, how its β̂ scores the labelled corrections (those the
    person was asked for: 1 toward a preference, 0 a nudge), :func:`~corrections_sim.metrics.
    label_scores`. Empty without labels."""
    out = {}
    for name in learners:
        rows = [
            r
            for r in records
            if r["learner"] == name and "relevant" in r and r.get("relevance") is not None
        ]
        if rows:
            out[name] = label_scores([r["relevance"] for r in rows], [r["relevant"] for r in rows])
    return out


def same_machine(log: StudyLog, session_id: int) -> bool | None:
    """Whether every machine the session was logged on (its ``machine`` events: the start and
    each resume) is this one, as :func:`corrections_sim.provenance.machine` tells them apart;
    None for a log without them (made before they were logged)."""
    logged = [e["detail"] for e in log.events(session_id, "machine")]
    if not logged:
        return None
    here = provenance.machine()
    return all(m == here for m in logged)


def same_atlas(log: StudyLog, session_id: int, settings: FigureSettings) -> bool | None:
    """Whether the plan atlas the session was logged with (its ``atlas`` event: the planner's
    build and options, the grid) is the one this replay plans from; None for a session
    planned without one. Where it is not, the replay's plans can differ from the session's."""
    logged = [e["detail"]["identity"] for e in log.events(session_id, "atlas")]
    spec = settings.atlas_spec()
    if spec is None:
        return None
    return bool(logged) and all(identity == spec.key(None) for identity in logged)


def write(settings: FigureSettings, result: FigureResult, facts: dict, folder) -> dict:
    """A replay's files in ``folder``, as a study writes them: ``curves.csv`` and, where a
    stated θ gives error, regret and NEES, the plot (PNG, PDF); returns the summary's fields."""
    from pathlib import Path

    from corrections_sim.figures.learning_study import write as write_study
    from corrections_sim.figures.output import write_records

    folder = Path(folder)
    if facts["stated_theta"] is not None and "regret" in result.records[0]:
        corrector = facts["corrector"]
        who = (
            f"corrected by a person ({facts['participant']}), θ* = the stated θ"
            if corrector == "person"
            else f"corrected by the simulated {corrector.get('name', corrector)} user"
        )
        fields = write_study(settings, result, folder, settings.name, user=who)
        (folder / "mean_estimate.csv").unlink(missing_ok=True)  # no mean over one run
    else:
        write_records(folder / "curves.csv", result.records)
        fields = {}
    return {"replay": facts, **fields}
