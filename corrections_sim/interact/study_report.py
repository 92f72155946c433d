"""``run analyze LOG``: a study log's tidy tables, its analysis and a report.

Reads a log a protocol's study wrote (people at the page, or a simulated cohort) and writes,
into one folder:

* ``corrections.csv`` (one row per confirmed correction), ``trials.csv`` (one row per
  finished trial: its condition, period, final error, mean regret, seconds per correction),
  ``answers.csv`` (one row per answered item);
* ``summary.json`` — per-condition means with CIs, the mixed model of each outcome
  (:func:`corrections_sim.study.user_study.mixed_model`), paired comparisons;
* ``participants.png`` (each participant's line over the conditions), ``conditions.png``
  (condition means with 95% CIs), ``questionnaires.png`` (the answers' distributions);
* ``report.md`` tying them together.

Withdrawn participants, aborted trials and the practice are left out (and counted). A log
with simulated participants says so at the top of the report and in ``summary.json``:
their answers come from a stated response model, not from people.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np

from corrections_sim.interact.log import StudyLog
from corrections_sim.interact.participant import experienced
from corrections_sim.interact.session import settings_from_log
from corrections_sim.study import user_study
from corrections_sim.study.protocol import TLX_SCALES, Protocol, parse_protocol

#: The outcomes of a trial the analysis models (``mean_regret`` needs the planner, see
#: :func:`tidy`; ``seconds`` is left out for simulated participants, whose seconds are CPU's).
OUTCOMES = ("final_error", "mean_regret", "seconds")


def protocol_of(log: StudyLog) -> Protocol:
    """The protocol a study log was run with (kept in its ``meta``)."""
    text = log.meta("protocol")
    if text is None:
        raise ValueError(f"{log.path}: not a protocol's study log (no protocol in it)")
    return parse_protocol(json.loads(text))


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
    excluded = {"withdrawn": [], "aborted_trials": 0, "unfinished_trials": 0}
    simulated = False
    people = []
    for person in log.participants():
        code, index = person["code"], int(person["index"])
        if person["withdrawn"] is not None:
            excluded["withdrawn"].append(code)
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
            trial = {
                **base,
                "corrections": len(logged),
                "final_error": math.nan if final is None else _error(final, reference),
                "mean_regret": math.nan,
                "seconds": float(np.mean([c["seconds"] for c in logged])) if logged else math.nan,
            }
            felt = log.events(sid, "experienced")
            if felt:  # a simulated participant's, computed when they answered
                trial["mean_regret"] = float(felt[-1]["detail"]["regret"])
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
                }
            )
    return {
        "protocol": protocol,
        "participants": people,
        "corrections": corrections,
        "trials": trials,
        "answers": answers,
        "excluded": excluded,
        "simulated": simulated,
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
    """Summaries, mixed models and paired comparisons of every outcome (see the module)."""
    protocol = tables["protocol"]
    conditions = list(protocol.names)
    outcomes = [o for o in OUTCOMES if not (o == "seconds" and tables["simulated"])]
    answer_rows, answer_names = answer_outcomes(tables)
    out: dict = {
        "simulated": tables["simulated"],
        "participants": len(tables["participants"]),
        "excluded": tables["excluded"],
        "conditions": conditions,
        "outcomes": {},
    }
    for name, rows in [
        *((o, tables["trials"]) for o in outcomes),
        *((o, answer_rows) for o in answer_names),
    ]:
        entry = {
            "summary": user_study.condition_summary(rows, name, conditions),
            "paired": user_study.paired(rows, name, conditions),
        }
        try:
            entry["mixed"] = user_study.mixed_model(rows, name, conditions)
        except ValueError as exc:
            entry["mixed"] = {"error": str(exc)}
        out["outcomes"][name] = entry
    return out


def _write_csv(path: Path, rows: list[dict]) -> None:
    columns: list[str] = []
    for row in rows:
        columns += [c for c in row if c not in columns]
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns)
        writer.writeheader()
        writer.writerows(rows)


def plot(tables: dict, result: dict, out: Path) -> list[Path]:
    """participants.png, conditions.png, questionnaires.png (see the module)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    conditions = result["conditions"]
    names = list(result["outcomes"])
    answer_rows, _ = answer_outcomes(tables)
    simulated = " (simulated participants)" if result["simulated"] else ""
    paths = []
    cols = min(3, len(names))
    rows = math.ceil(len(names) / cols)
    for kind in ("participants", "conditions"):
        fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.2 * rows), squeeze=False)
        for ax, name in zip(axes.flat, names, strict=False):
            source = tables["trials"] if name in OUTCOMES else answer_rows
            x = np.arange(len(conditions))
            if kind == "participants":
                per: dict[str, dict[str, list[float]]] = {}
                for t in source:
                    if name in t and np.isfinite(float(t[name])):
                        per.setdefault(t["participant"], {}).setdefault(t["condition"], []).append(
                            float(t[name])
                        )
                for values in per.values():
                    y = [np.mean(values[c]) if c in values else np.nan for c in conditions]
                    ax.plot(x, y, "-o", color="0.45", alpha=0.55, lw=1, ms=3)
            summary = result["outcomes"][name]["summary"]
            means = np.array([s["mean"] for s in summary])
            lo = np.array([s["lo"] for s in summary])
            hi = np.array([s["hi"] for s in summary])
            ax.errorbar(
                x,
                means,
                yerr=[means - lo, hi - means],
                fmt="s",
                color="C3",
                capsize=5,
                lw=2,
                ms=7,
                zorder=3,
                label="mean, 95% CI",
            )
            ax.set_xticks(x, conditions)
            ax.set_xlim(-0.5, len(conditions) - 0.5)
            ax.set_title(name.replace("_", " "))
            ax.grid(alpha=0.3)
        for ax in list(axes.flat)[len(names) :]:
            ax.axis("off")
        what = "each participant (grey) and" if kind == "participants" else ""
        fig.suptitle(f"By condition: {what} the mean with its 95% CI{simulated}")
        fig.tight_layout()
        path = out / f"{kind}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths.append(path)
    likert = [a for a in tables["answers"] if a["kind"] == "likert"]
    items = list(dict.fromkeys(a["item"] for a in likert))
    if items:
        fig, axes = plt.subplots(1, len(items), figsize=(3.6 * len(items), 3.2), squeeze=False)
        for ax, item in zip(axes.flat, items, strict=True):
            mine = [a for a in likert if a["item"] == item]
            points = int(mine[0]["points"])
            present = {a["condition"] or "end" for a in mine}
            groups = [g for g in (*conditions, "end") if g in present]
            width = 0.8 / len(groups)
            for g, group in enumerate(groups):
                values = [a["value"] for a in mine if (a["condition"] or "end") == group]
                counts = np.bincount(values, minlength=points + 1)[1:]
                ax.bar(
                    np.arange(1, points + 1) + (g - (len(groups) - 1) / 2) * width,
                    counts,
                    width,
                    label=group,
                )
            ax.set_xticks(range(1, points + 1))
            ax.set_title(item)
            ax.set_xlabel("answer")
            ax.legend(fontsize=8)
        axes.flat[0].set_ylabel("participants")
        fig.suptitle(f"Questionnaire answers{simulated}")
        fig.tight_layout()
        path = out / "questionnaires.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths.append(path)
    return paths


def _number(x, digits: int = 3) -> str:
    return "—" if x is None or not np.isfinite(x) else f"{x:.{digits}f}"


def report(tables: dict, result: dict, log_path: Path) -> str:
    """The Markdown report (see the module)."""
    protocol = tables["protocol"]
    lines = [f"# Study report: {protocol.description or log_path.name}", ""]
    if result["simulated"]:
        lines += [
            "> **Simulated participants.** Every participant in this log was simulated "
            "(θ* drawn from the protocol's population, corrections by a simulated user); "
            "their questionnaire answers come from the protocol's response model, not from "
            "people.",
            "",
        ]
    ex = result["excluded"]
    lines += [
        f"Log `{log_path.name}`; {result['participants']} participants analysed; "
        f"withdrawn and left out: {len(ex['withdrawn'])}; aborted trials left out: "
        f"{ex['aborted_trials']}; unfinished trials: {ex['unfinished_trials']}. Conditions: "
        + ", ".join(f"{c.name} ({c.learner}, {c.mode})" for c in protocol.conditions)
        + f"; order by {protocol.order} square; {protocol.trials} trial(s) of "
        f"{protocol.corrections} corrections per condition.",
        "",
        "Tables: `trials.csv`, `corrections.csv`, `answers.csv`; numbers: `summary.json`.",
        "",
        "## Outcomes by condition (mean over participants, 95% t CI)",
        "",
        "| outcome | " + " | ".join(result["conditions"]) + " |",
        "|---|" + "---|" * len(result["conditions"]),
    ]
    for name, entry in result["outcomes"].items():
        cells = [
            f"{_number(s['mean'])} [{_number(s['lo'])}, {_number(s['hi'])}]"
            for s in entry["summary"]
        ]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "## Mixed model: condition (fixed), participant (random)",
        "",
        "`outcome ~ condition + period + (1 | participant)`, REML; the interval is t with the "
        "between-within degrees of freedom.",
        "",
        "| outcome | effect | estimate | 95% CI | df | p | participant var | residual var |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, entry in result["outcomes"].items():
        mixed = entry["mixed"]
        if "error" in mixed:
            lines.append(f"| {name} | — | {mixed['error']} | | | | | |")
            continue
        for e in mixed["effects"]:
            flag = "" if mixed["converged"] else " (did not converge)"
            lines.append(
                f"| {name} | {e['condition']} − {e['against']}{flag} | {_number(e['estimate'])} "
                f"| [{_number(e['lo'])}, {_number(e['hi'])}] | {e['df']} | {_number(e['p'])} "
                f"| {_number(mixed['participant_variance'])} "
                f"| {_number(mixed['residual_variance'])} |"
            )
    lines += [
        "",
        "## Paired comparisons (each participant's difference)",
        "",
        "| outcome | difference | n | mean | 95% CI | d_z | p |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, entry in result["outcomes"].items():
        for p in entry["paired"]:
            lines.append(
                f"| {name} | {p['b']} − {p['a']} | {p['n']} | {_number(p['mean'])} | "
                f"[{_number(p['lo'])}, {_number(p['hi'])}] | {_number(p['d_z'], 2)} | "
                f"{_number(p['p'])} |"
            )
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
        lines += ["## Free text", ""]
        lines += [f"- {a['participant']} ({a['item']}): {a['value']}" for a in texts[:50]]
        lines.append("")
    return "\n".join(lines)


def analyze(log_path, out, *, regret: bool = True) -> list[Path]:
    """Everything of the module for the log at ``log_path``, into the folder ``out``."""
    log_path = Path(log_path)
    if not log_path.is_file():
        raise ValueError(f"{log_path}: no such study log")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    with StudyLog(log_path) as log:
        tables = tidy(log, regret=regret)
    if not tables["trials"]:
        raise ValueError(f"{log_path}: no finished trial to analyse")
    result = analyse(tables)
    paths = []
    for name in ("corrections", "trials", "answers"):
        path = out / f"{name}.csv"
        _write_csv(path, tables[name])
        paths.append(path)
    path = out / "summary.json"
    path.write_text(json.dumps(result, indent=1, default=float) + "\n")
    paths.append(path)
    paths += plot(tables, result, out)
    path = out / "report.md"
    path.write_text(report(tables, result, log_path))
    paths.append(path)
    return paths
