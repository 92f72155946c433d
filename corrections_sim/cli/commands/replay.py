"""``replay``: a logged session replayed through any learners, written as a study."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from corrections_sim import provenance
from corrections_sim.cli.command import Command, wrote_nothing
from corrections_sim.cli.common import out_dir, staged, writable_dir
from corrections_sim.cli.errors import UsageError
from corrections_sim.defaults import DEFAULTS


def _learner_sets(items) -> dict[str, dict]:
    """``--set learners.NAME.KEY=VALUE`` items as {NAME: {KEY: value}} (a replay changes its
    learners only: the environments, features and prior are the session's)."""
    from corrections_sim.study.files import parse_value

    out: dict[str, dict] = {}
    for item in items:
        path, sep, text = item.partition("=")
        parts = path.strip().split(".")
        if not sep or len(parts) < 3 or parts[0] != "learners" or not all(parts):
            raise UsageError(
                f"--set {item}: a replay sets learners' parameters only, "
                "e.g. learners.KF-CR.model=physical"
            )
        node = out.setdefault(parts[1], {})
        for key in parts[2:-1]:
            node = node.setdefault(key, {})
        node[parts[-1]] = parse_value(text.strip())
    return out


def run_replay(args: argparse.Namespace) -> list[Path]:
    """A logged session replayed through learners, written as a study (curves.csv, the
    plot, summary.json) in OUT/replay-<session>/."""
    from corrections_sim.session.log import LogError, StudyLog
    from corrections_sim.session.replay import replay, write

    if not args.study_file:
        raise UsageError("replay: give the database, e.g. replay results/interact/study.sqlite")
    db = Path(args.study_file)
    if not db.is_file():
        raise UsageError(f"{db}: no such database")
    try:
        log = StudyLog(db)
        ids = log.session_ids()
        session = args.session if args.session is not None else (ids[-1] if ids else None)
        if session is None:
            raise UsageError(f"{db}: no sessions")
        settings, result, facts = replay(
            log, session, args.learners, params=_learner_sets(args.set or ())
        )
    except (LogError, ValueError) as exc:
        raise UsageError(str(exc).splitlines()[0]) from None
    out = writable_dir(out_dir(args))
    final = out / f"replay-{session}"
    with staged(final) as staging:
        fields = write(settings, result, facts, staging)
        summary = {"figure": final.name, "settings": settings.as_dict(), **fields}
        summary.update(provenance.record(args.argv))
        (staging / "summary.json").write_text(
            json.dumps(provenance.plain(summary), indent=2) + "\n"
        )
        names = sorted(p.name for p in staging.iterdir())
    if facts["left_out"]:
        print(
            f"replay: {', '.join(facts['left_out'])} left out: they need the study's plan atlas, "
            f"and this session's study had none",
            file=sys.stderr,
        )
    for name, entry in facts["final"].items():
        error = entry["estimate_error"]
        tail = "" if error is None else f", error {error:.3f} against the stated θ"
        print(f"{name}: θ̂ = {np.round(entry['theta'], 3).tolist()}{tail}", file=sys.stderr)
    for entry in facts.get("learnt_features", []):
        weight = entry["weight"]
        said = "" if weight is None else f", final weight {weight:+.3f}"
        said += "" if entry["sd"] is None else f" ± {entry['sd']:.3f}"
        if entry.get("logged_weight") is not None:
            said += f" (the session logged {entry['logged_weight']:+.3f})"
        for true, q in entry["quality"].items():
            said += f"; against {true}: Spearman {q['spearman']:.3f}, R² {q['r2']:.3f}"
        print(
            f"learnt feature {entry['feature']} (after correction {entry['after']}, from "
            f"{entry['traces']} traces){said}",
            file=sys.stderr,
        )
    for name, score in facts.get("labelled", {}).items():
        if score["auc"] is None:  # one kind only: nothing to rank
            continue
        low, high = score["auc_ci95"]
        print(
            f"{name} on the {score['toward']} + {score['nudges']} labelled corrections: ROC AUC "
            f"{score['auc']:.3f} [{low:.3f}, {high:.3f}], median β̂ {score['median_toward']:.3f}"
            f" toward, {score['median_nudge']:.3g} nudges",
            file=sys.stderr,
        )
    return [final / n for n in names]


COMMAND = Command(
    name="replay",
    run=run_replay,
    help="replay a logged session (FILE: the database) through learners",
    options=("study_file", "out", "session", "learners", "set"),
    file="LOG",
    option_help={
        "study_file": "the study log to replay (the SQLite database interact wrote)",
        "set": "change a replayed learner's parameter, learners.NAME.KEY=VALUE, e.g. "
        "learners.KF-C.model=physical (repeatable; any other key is refused)",
        "learners": "which learners to replay, any registered ones (default "
        f"{','.join(DEFAULTS['replay'])} and the session's own); their parameters are the "
        "session's",
    },
    nothing_kept=wrote_nothing,
)
