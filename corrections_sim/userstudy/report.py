"""``run analyze LOG``: a study log's tidy tables, its analysis and a report.

Reads a log a protocol's study wrote (people at the page, or a simulated cohort) and writes,
into one folder:

* ``corrections.csv`` (one row per confirmed correction), ``trials.csv`` (one row per
  finished trial: its condition, period, final error, mean regret, seconds per correction),
  ``answers.csv`` (one row per answered item);
* ``summary.json`` — per-condition means with CIs, the mixed model of each outcome
  (:func:`corrections_sim.userstudy.statistics.mixed_model`), paired comparisons;
* ``participants.png`` (each participant's line over the conditions), ``conditions.png``
  (condition means with 95% CIs), ``questionnaires.png`` (the answers' distributions);
* ``report.md`` tying them together.

Withdrawn participants, aborted trials and the practice are left out (and counted); so are
trials that ended early (a participant who stopped, or fewer than ``min_corrections``) from
every trial outcome, and a trial without a stated preference has no error or regret (counted).
A log with simulated participants says so at the top of the report and in ``summary.json``:
their answers come from a stated response model, not from people.

**What the report refuses to say** (:mod:`corrections_sim.userstudy.statistics`): below the
protocol's ``min_participants`` it is descriptive only (means, spreads, each person's values;
no interval, test or model); a saturated or singular mixed model is not reported (the report
says why and shows the paired comparison); intervals of bounded scales stay on their scale;
an end item that compares the robots is mapped to the conditions by each participant's order;
``summary.json`` is strict JSON (a number that does not exist is ``null``); free text is
escaped.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np

from corrections_sim.session.log import StudyLog
from corrections_sim.session.session import settings_from_log
from corrections_sim.userstudy import statistics
from corrections_sim.userstudy.participant import experienced, logged_experience
from corrections_sim.userstudy.plots import plot
from corrections_sim.userstudy.protocol import OUTCOMES, TLX_SCALES, Protocol, parse_protocol
from corrections_sim.userstudy.typed import as_typed


def protocol_of(log: StudyLog) -> Protocol:
    """The protocol a study log was run with (kept in its ``meta``)."""
    text = log.meta("protocol")
    if text is None:
        raise ValueError(f"{log.path}: not a protocol's study log (no protocol in it)")
    return parse_protocol(json.loads(text), strict=False)


def outcome_bounds(name: str, protocol: Protocol) -> statistics.Bounds:
    """The scale of an outcome: errors and seconds are >= 0, a Likert item 1…points, the raw
    TLX 0…100; the regret of a plan is unbounded (a local optimum can make it negative)."""
    if name in ("final_error", "seconds"):
        return (0.0, None)
    if name.endswith("_raw"):
        return (0.0, 100.0)
    for q in (*protocol.after_condition, *protocol.at_end):
        if q.id == name and q.kind == "likert":
            return (1.0, float(q.points))
    return statistics.UNBOUNDED


def _error(theta, reference) -> float:
    if reference is None:
        return math.nan
    reference = np.asarray(reference, float)
    scale = float(np.sum(np.abs(reference)))
    if scale == 0.0:
        return math.nan
    return float(np.sum(np.abs(np.asarray(theta, float) - reference)) / scale)


def tidy(log: StudyLog, *, regret: bool = True) -> dict:
    """{corrections, trials, answers, participants, excluded, simulated, protocol} of ``log``
    (see the module); ``regret``: plan each trial's environments under the participant's
    stated θ for the regret of the plans shown (seconds of planning per trial)."""
    protocol = protocol_of(log)
    corrections, trials, answers = [], [], []
    excluded = {
        "withdrawn": [],
        "withdrew_themselves": [],
        "aborted_trials": 0,
        "unfinished_trials": 0,
        "ended_early_trials": 0,
        "trials_without_stated_preference": 0,
    }
    simulated = False
    people = []
    comparisons = []
    asked = log.asked()
    for person in log.participants():
        code, index = person["code"], int(person["index"])
        if person["withdrawn"] is not None:
            excluded["withdrawn"].append(code)
            left = log.participant_events(code, "withdrew")
            if left and left[-1]["detail"].get("by") == "participant":
                excluded["withdrew_themselves"].append(code)
            continue
        simulated |= person["simulated"] is not None
        people.append(code)
        steps = protocol.steps(index)
        order = protocol.order_of(index)
        rows = {r["position"]: r for r in log.steps(code)}
        for position, step in enumerate(steps):
            row = rows.get(position)
            if row is not None:
                excluded["aborted_trials"] += len(row["aborted"])
            if step.kind != "trial" or step.trial == 0:
                continue
            if row is None or row["finished"] is None or row["session_id"] is None:
                excluded["unfinished_trials"] += 1
                continue
            sid = int(row["session_id"])
            session = log.session(sid)
            logged = log.corrections(sid)
            reference = session.stated_theta
            base = {
                "participant": code,
                "index": index,
                "simulated": person["simulated"] is not None,
                "condition": step.condition,
                "learner": session.learner,
                "trial": step.trial,
                "period": order.index(step.condition) + 1,
                "session": sid,
            }
            for c in logged:
                corrections.append(
                    {
                        **base,
                        "iteration": int(c["iteration"]),
                        "env_index": int(c["env_index"]),
                        "env_name": c["env_name"],
                        **{f"theta_{i}": float(v) for i, v in enumerate(c["theta_after"])},
                        "error": _error(c["theta_after"], reference),
                        "nis": c["nis"],
                        "seconds": float(c["seconds"]),
                        "update_skipped": c["update_skipped"],
                    }
                )
            final = logged[-1]["theta_after"] if logged else None
            stopped = bool(log.events(sid, "stopped"))
            early = stopped or len(logged) < protocol.minimum
            excluded["ended_early_trials"] += early
            excluded["trials_without_stated_preference"] += reference is None
            trial = {
                **base,
                "corrections": len(logged),
                "ended_early": early,
                "stopped_by_participant": stopped,
                "stated": reference is not None,
                "final_error": math.nan if final is None else _error(final, reference),
                "mean_regret": math.nan,
                "seconds": float(np.mean([c["seconds"] for c in logged])) if logged else math.nan,
            }
            felt = logged_experience(log.events(sid, "experienced"))
            if felt is not None:  # a simulated participant's, computed when they answered
                trial["mean_regret"] = float(felt["regret"])
            elif regret and reference is not None and logged:
                settings = settings_from_log(session.settings)
                trial["mean_regret"] = experienced(settings, logged, reference)["regret"]
            trials.append(trial)
        for a in log.answers(code):
            step = next((s for s in steps if s.key == a["step"]), None)
            if step is None:
                continue
            item = a["item"]
            qid = item.split(".")[0]
            question = next(q for q in step.questions if q.id == qid)
            # What was asked: kept beside the answer (logs made before: the protocol's).
            shown = asked.get((code, a["step"], item)) or question.asked(item)
            answers.append(
                {
                    "participant": code,
                    "index": index,
                    "simulated": person["simulated"] is not None,
                    "step": a["step"],
                    "condition": step.condition or "",
                    "period": order.index(step.condition) + 1 if step.condition else 0,
                    "item": item,
                    "kind": question.kind,
                    "points": question.points if question.kind == "likert" else "",
                    "value": a["value"],
                    "question": shown.get("text", ""),
                    "anchors": " … ".join(shown.get("anchors", [])),
                }
            )
            if question.compare and len(order) == 2:
                comparisons.append(compared(code, item, int(a["value"]), question.points, order))
    return {
        "protocol": protocol,
        "participants": people,
        "corrections": corrections,
        "trials": trials,
        "answers": answers,
        "comparisons": comparisons,
        "excluded": excluded,
        "simulated": simulated,
    }


def compared(code: str, item: str, value: int, points: int, order: tuple[str, ...]) -> dict:
    """An answer to an item that compares the robots, mapped to the conditions: the low
    anchor is the robot the participant met first (``order[0]``), the high one the second.
    ``preferred``: the condition they leant to ("" at the middle); ``score``: how far toward
    the protocol's second condition (sorted by the conditions' names), −(points−1)/2 …
    +(points−1)/2."""
    mid = (points + 1) / 2
    toward_second_met = value - mid
    first, second = order
    preferred = "" if value == mid else (second if value > mid else first)
    names = sorted(order)
    score = toward_second_met if second == names[1] else -toward_second_met
    return {
        "participant": code,
        "item": item,
        "value": value,
        "first": first,
        "second": second,
        "preferred": preferred,
        "toward": names[1],
        "score": score,
    }


def answer_outcomes(tables: dict) -> tuple[list[dict], list[str]]:
    """Per participant and condition, each Likert item and the raw TLX (mean of its six
    subscales) as trial-like rows the model takes; and their names."""
    rows: dict[tuple, dict] = {}
    names: list[str] = []
    tlx: dict[tuple, list[float]] = {}
    for a in tables["answers"]:
        if not a["condition"] or a["kind"] == "text":
            continue
        key = (a["participant"], a["condition"])
        row = rows.setdefault(
            key,
            {"participant": a["participant"], "condition": a["condition"], "period": a["period"]},
        )
        if a["kind"] == "likert":
            row[a["item"]] = float(a["value"])
            if a["item"] not in names:
                names.append(a["item"])
        else:
            qid = a["item"].split(".")[0]
            tlx.setdefault((*key, qid), []).append(float(a["value"]))
    for (participant, condition, qid), values in tlx.items():
        if len(values) == len(TLX_SCALES):
            rows[(participant, condition)][f"{qid}_raw"] = float(np.mean(values))
            if f"{qid}_raw" not in names:
                names.append(f"{qid}_raw")
    return list(rows.values()), names


def analyse(tables: dict) -> dict:
    """Summaries, mixed models and paired comparisons of every outcome (see the module);
    below the protocol's ``min_participants`` the summaries alone, marked descriptive."""
    protocol = tables["protocol"]
    conditions = list(protocol.names)
    # mean_regret needs the planner (see tidy); seconds are left out for simulated
    # participants, whose seconds are CPU's.
    outcomes = [o for o in OUTCOMES if not (o == "seconds" and tables["simulated"])]
    answer_rows, answer_names = answer_outcomes(tables)
    complete = [t for t in tables["trials"] if not t.get("ended_early")]
    n = len(tables["participants"])
    descriptive = n < protocol.min_participants
    out: dict = {
        "simulated": tables["simulated"],
        "participants": n,
        "min_participants": protocol.min_participants,
        "descriptive_only": descriptive,
        "primary": protocol.primary,
        "excluded": tables["excluded"],
        "conditions": conditions,
        "outcomes": {},
    }
    for name, rows in [
        *((o, complete) for o in outcomes),
        *((o, answer_rows) for o in answer_names),
    ]:
        bounds = outcome_bounds(name, protocol)
        summary = statistics.condition_summary(rows, name, conditions, bounds)
        pairs = statistics.paired(rows, name, conditions, bounds)
        entry: dict = {"bounds": list(bounds), "summary": summary, "paired": pairs}
        if descriptive:
            for row in (*summary, *pairs):
                for key in ("lo", "hi", "d_z", "p"):
                    row.pop(key, None)
            entry["mixed"] = {"reported": False, "why": "descriptive only (too few participants)"}
        else:
            try:
                entry["mixed"] = statistics.mixed_model(rows, name, conditions)
            except ValueError as exc:
                entry["mixed"] = {"reported": False, "why": str(exc)}
            _flag_beyond_scale(entry["mixed"], bounds)
        out["outcomes"][name] = entry
    out["comparisons"] = compare_summary(tables["comparisons"], protocol, descriptive)
    return out


def _flag_beyond_scale(mixed: dict, bounds: statistics.Bounds) -> None:
    """A reported effect whose interval runs past the largest difference the scale allows
    says nothing the scale can hold: not reported."""
    low, high = statistics.difference_bounds(bounds)
    if not mixed.get("reported") or low is None:
        return
    for e in mixed["effects"]:
        if e["lo"] < low or e["hi"] > high:
            mixed["reported"] = False
            mixed["why"] = (
                f"its interval [{e['lo']:.2f}, {e['hi']:.2f}] runs past the scale's largest "
                f"difference (±{high:g}): too few data for the model"
            )
            return


def compare_summary(rows: list[dict], protocol: Protocol, descriptive: bool) -> dict:
    """Per item that compares the robots: how many preferred each condition (and neither),
    the mean score toward the second condition by name, with a t interval on its scale and
    a sign test (not below ``min_participants``)."""
    out = {}
    for item in dict.fromkeys(r["item"] for r in rows):
        mine = [r for r in rows if r["item"] == item]
        question = next(q for q in protocol.at_end if q.id == item)
        reach = (question.points - 1) / 2
        toward = mine[0]["toward"]
        names = sorted({mine[0]["first"], mine[0]["second"]})
        counts = {name: sum(r["preferred"] == name for r in mine) for name in names}
        entry = {
            "toward": toward,
            "preferred": counts,
            "neither": sum(r["preferred"] == "" for r in mine),
            **statistics.mean_ci([r["score"] for r in mine], bounds=(-reach, reach)),
            "sign_test_p": statistics.sign_test(counts[names[1]], counts[names[0]]),
        }
        if descriptive:
            for key in ("lo", "hi", "sign_test_p"):
                entry.pop(key)
        out[item] = entry
    return out


def strict_json(value):
    """``value`` with every float that is not a number (NaN, ±inf) as None: JSON as the
    standard has it (Python's json writes NaN, which other readers refuse)."""
    if isinstance(value, dict):
        return {k: strict_json(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [strict_json(v) for v in value]
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


def escape_text(text: str, limit: int = 500) -> str:
    """Free text as plain words in Markdown (:func:`~corrections_sim.userstudy.typed.as_typed`),
    every run of white space one space, at most ``limit`` characters (the rest marked cut)."""
    flat = " ".join(str(text).split())
    return as_typed(flat[:limit]) + (" [cut]" if len(flat) > limit else "")


def _write_csv(path: Path, rows: list[dict]) -> None:
    columns: list[str] = []
    for row in rows:
        columns += [c for c in row if c not in columns]
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns)
        writer.writeheader()
        writer.writerows(rows)


def _number(x, digits: int = 3) -> str:
    return "—" if x is None or not np.isfinite(x) else f"{x:.{digits}f}"


def _head(columns: list[str], inferential: list[str], descriptive: bool) -> list[str]:
    """A Markdown table's header and rule: ``columns``, and ``inferential`` unless the report
    is descriptive only."""
    names = columns + ([] if descriptive else inferential)
    return ["| " + " | ".join(names) + " |", "|" + "---|" * len(names)]


def _interval(row: dict) -> str:
    if "lo" not in row:
        return ""
    return f" [{_number(row['lo'])}, {_number(row['hi'])}]"


def report(tables: dict, result: dict, log_path: Path) -> str:
    """The Markdown report (see the module)."""
    protocol = tables["protocol"]
    descriptive = result["descriptive_only"]
    lines = [f"# Study report: {escape_text(protocol.description or log_path.name)}", ""]
    if result["simulated"]:
        lines += [
            "> **Simulated participants.** Every participant in this log was simulated "
            "(θ* drawn from the protocol's population, corrections by a simulated user); "
            "their questionnaire answers come from the protocol's response model, not from "
            "people.",
            "",
        ]
    n, least = result["participants"], result["min_participants"]
    if descriptive:
        lines += [
            f"> **Descriptive only.** {n} {'participant' if n == 1 else 'participants'}, fewer "
            f"than the protocol's min_participants ({least}): no interval, test or model is "
            "reported. The numbers describe these participants and say nothing about "
            "anyone else.",
            "",
        ]
    ex = result["excluded"]
    themselves = len(ex.get("withdrew_themselves", []))
    lines += [
        f"Log `{log_path.name}`; **{n} participants analysed**. Left out: withdrawn "
        f"{len(ex['withdrawn'])} ({themselves} by their own choice); aborted trials "
        f"{ex['aborted_trials']}; trials never finished {ex['unfinished_trials']}; trials "
        f"ended early {ex.get('ended_early_trials', 0)} (fewer than {protocol.minimum} "
        "corrections, or stopped by the participant: out of every trial outcome); trials "
        f"without a stated preference {ex.get('trials_without_stated_preference', 0)} (no "
        "error or regret). Conditions: "
        + ", ".join(f"{c.name} ({c.learner}, {c.mode})" for c in protocol.conditions)
        + f"; order by {protocol.order} square; {protocol.trials} trial(s) of "
        f"{protocol.corrections} corrections per condition. Primary outcome: "
        f"**{protocol.primary}**.",
        "",
        "Tables: `trials.csv`, `corrections.csv`, `answers.csv`, `comparisons.csv`; numbers: "
        "`summary.json`.",
        "",
        "## Outcomes by condition",
        "",
        (
            "Mean over participants (sd; range of the participants' means)."
            if descriptive
            else "Mean over participants with its 95% t interval, computed on the outcome's "
            "scale (a Likert item 1…points, the TLX 0…100, errors and seconds ≥ 0)."
        ),
        "",
        "| outcome | " + " | ".join(result["conditions"]) + " |",
        "|---|" + "---|" * len(result["conditions"]),
    ]
    for name, entry in result["outcomes"].items():
        cells = []
        for row in entry["summary"]:
            if descriptive:
                cells.append(
                    f"{_number(row['mean'])} (sd {_number(row['sd'])}; {_number(row['min'])}…"
                    f"{_number(row['max'])}), n {row['n']}"
                )
            else:
                cells.append(f"{_number(row['mean'])}{_interval(row)}, n {row['n']}")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    if not descriptive:
        lines += [
            "",
            "## Mixed model: condition (fixed), participant (random)",
            "",
            "`outcome ~ condition + period + (1 | participant)`, REML; the interval is t with "
            "the between-within degrees of freedom. A saturated or singular model is not a "
            "result: its row says why, and the paired comparison below stands instead.",
            "",
            "| outcome | effect | estimate | 95% CI | df | p | participant var | residual var |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for name, entry in result["outcomes"].items():
            mixed = entry["mixed"]
            if not mixed.get("reported"):
                lines.append(f"| {name} | not reported: {mixed['why']} | | | | | | |")
                continue
            for e in mixed["effects"]:
                lines.append(
                    f"| {name} | {e['condition']} − {e['against']} | {_number(e['estimate'])} "
                    f"| [{_number(e['lo'])}, {_number(e['hi'])}] | {e['df']} | {_number(e['p'])} "
                    f"| {_number(mixed['participant_variance'])} "
                    f"| {_number(mixed['residual_variance'])} |"
                )
    lines += [
        "",
        "## Paired comparisons (each participant's difference)",
        "",
        *_head(["outcome", "difference", "n", "mean", "sd"], ["95% CI", "d_z", "p"], descriptive),
    ]
    for name, entry in result["outcomes"].items():
        for p in entry["paired"]:
            row = (
                f"| {name} | {p['b']} − {p['a']} | {p['n']} | {_number(p['mean'])} | "
                f"{_number(p['sd'])} |"
            )
            if not descriptive:
                row += (
                    f" [{_number(p['lo'])}, {_number(p['hi'])}] | {_number(p['d_z'], 2)} | "
                    f"{_number(p['p'])} |"
                )
            lines.append(row)
    if result["comparisons"]:
        lines += [
            "",
            "## Which robot they would rather work with",
            "",
            "Each answer mapped to the conditions by the participant's own order (the low "
            "anchor is the robot they met first). Score: toward the condition named, "
            "−(points−1)/2 … +(points−1)/2.",
            "",
            *_head(
                ["item", "preferred", "neither", "score toward", "mean score"],
                ["95% CI", "sign test p"],
                descriptive,
            ),
        ]
        for item, c in result["comparisons"].items():
            preferred = ", ".join(f"{k} {v}" for k, v in c["preferred"].items())
            mean = _number(c["mean"])
            row = f"| {item} | {preferred} | {c['neither']} | {c['toward']} | {mean} |"
            if not descriptive:
                row += f"{_interval(c)} | {_number(c['sign_test_p'])} |"
            lines.append(row)
    lines += [
        "",
        "## Figures",
        "",
        "![each participant over the conditions](participants.png)",
        "",
        "![condition means](conditions.png)",
        "",
    ]
    if any(a["kind"] == "likert" for a in tables["answers"]):
        lines += ["![questionnaire answers](questionnaires.png)", ""]
    texts = [a for a in tables["answers"] if a["kind"] == "text" and a["value"]]
    if texts:
        lines += ["## Free text (as written, escaped)", ""]
        lines += [
            f"- {escape_text(a['participant'])} ({escape_text(a['item'])}): "
            f"{escape_text(a['value'])}"
            for a in texts[:50]
        ]
        lines.append("")
    return "\n".join(lines)


def analyze(log_path, out, *, regret: bool = True) -> list[Path]:
    """Everything of the module for the log at ``log_path``, into the folder ``out`` (made
    only once the log has been read and has a finished trial)."""
    log_path = Path(log_path)
    if not log_path.is_file():
        raise ValueError(f"{log_path}: no such study log")
    with StudyLog(log_path) as log:
        tables = tidy(log, regret=regret)
    if not tables["trials"]:
        raise ValueError(f"{log_path}: no finished trial to analyse")
    result = analyse(tables)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for name in ("corrections", "trials", "answers", "comparisons"):
        path = out / f"{name}.csv"
        _write_csv(path, tables[name])
        paths.append(path)
    path = out / "summary.json"
    path.write_text(json.dumps(strict_json(result), indent=1, allow_nan=False) + "\n")
    paths.append(path)
    paths += plot(tables, result, out, answer_outcomes(tables)[0])
    path = out / "report.md"
    path.write_text(report(tables, result, log_path))
    paths.append(path)
    return paths
