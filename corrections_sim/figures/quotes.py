"""Numbers the README and the docs quote from committed results, filled in from the files.

A page marks each quoted number or table with what it quotes, a name and its arguments::

    The main job took <!-- quote minutes fig4 -->19<!-- /quote --> minutes.
    KF-C ends at <!-- quote value fig4 final.KF-C.estimate_error.mean .3f -->0.633<!-- /quote -->.

    <!-- quote learners-table fig4 PP,KF,AL -->

    | after 12 corrections (mean ± SEM) | PP | KF | AL (1 run) |
    …

    <!-- /quote -->

The comments render as nothing (GitHub, MkDocs); what stands between them is what
:data:`QUOTES` computes from ``results/<figure>/summary.json`` (or another JSON file under
``results/``, named by its path there) now. ``python -m corrections_sim.run quotes`` lists
every quote of README.md and docs/*.md that differs from its file (exit status 1), and
``--fill`` rewrites them in place (:mod:`corrections_sim.cli.commands.quotes`); the test suite
runs the check, so a page and its file cannot disagree unnoticed.
"""

from __future__ import annotations

import csv
import functools
import json
import re
from collections.abc import Callable
from pathlib import Path

from corrections_sim.figures import report

#: ``<!-- quote NAME ARGS -->TEXT<!-- /quote -->``, TEXT inline or a block between blank lines.
PATTERN = re.compile(r"<!-- quote ([^>]+?) -->(.*?)<!-- /quote -->", re.DOTALL)


def _summary(root: Path, figure: str) -> dict:
    """``results/<figure>/summary.json``, or ``results/<figure>`` where it names a JSON file."""
    path = root / "results" / figure
    return json.loads((path if figure.endswith(".json") else path / "summary.json").read_text())


def _names(text: str) -> list[str]:
    return text.split(",")


def headline(root: Path) -> str:
    """Fig. 4's learners (all it shows) after the last correction: error, regret and mean
    NEES, with the band a calibrated mean NEES lies in (95%) for the most runs."""
    summary = _summary(root, "fig4")
    final, calib = summary["final"], summary["calibration"]
    names = list(final)
    runs = {n: final[n]["runs"] for n in names}
    n_runs = max(runs.values())
    once = [n for n in names if runs[n] == 1]
    iterations = summary["settings"]["iterations"]
    what = f"mean ± SEM over {n_runs} runs"
    if once:
        what += f"; {' and '.join(once)}: one deterministic run"
    lines = [
        f"| fig. 4 after {iterations} corrections ({what}) | " + " | ".join(names) + " |",
        "|---|" + "---|" * len(names),
    ]
    for key in ("estimate_error", "regret"):
        digits = 3 if key == "estimate_error" else 2
        cells = [report.pm(final[n][key], digits) for n in names]
        lines.append(f"| {report.METRIC_NAMES[key]} | " + " | ".join(cells) + " |")
    (band,) = {
        tuple(round(b, 2) for b in calib[n]["band"])
        for n in names
        if n in calib and runs[n] == n_runs
    }
    cells = []
    for n in names:
        if n not in calib:
            cells.append("— (no covariance)")
            continue
        value = calib[n]["mean_nees"][-1]
        low, high = calib[n]["band"]  # a single run's band is its own
        where = "inside" if low <= value <= high else ("above" if value > high else "below")
        cells.append(f"{value:.3g} ({where})")
    single = {tuple(calib[n]["band"]) for n in once if n in calib}
    alone = ""
    if single:
        (low, high), *_ = single
        alone = f", one run's in [{low:.2f}, {high:.2f}]"
    lines.append(
        f"| mean NEES (a calibrated mean of {n_runs} runs lies in [{band[0]:.2f}, {band[1]:.2f}]"
        f" in 95% of studies{alone}; above: over-confident, below: under-confident) | "
        + " | ".join(cells)
        + " |"
    )
    return "\n".join(lines)


def value(root: Path, figure: str, path: str, spec: str = "") -> str:
    """One value of ``figure``'s summary at the dotted ``path`` (a list index may be negative;
    ``_`` stands for a space in a key that has one), formatted by ``spec`` (Python's format
    mini-language, e.g. ``.3f``, ``,``)."""
    item = _summary(root, figure)
    for key in path.split("."):
        if isinstance(item, list):
            item = item[int(key)]
        else:
            item = item[key] if key in item else item[key.replace("_", " ")]
    return format(item, spec)


def final(root: Path, figure: str, learner: str, metric: str, digits: str = "3") -> str:
    """``learner``'s final mean ± SEM of ``metric`` in ``figure`` (one run: its value)."""
    stat = _summary(root, figure)["final"][learner]
    if stat["runs"] == 1:
        return f"{stat[metric]['mean']:.{int(digits)}f}"
    return report.pm(stat[metric], int(digits))


def _where(text: str) -> dict[str, str]:
    """``field=value;field=value`` as a dict."""
    return dict(part.split("=", 1) for part in text.split(";"))


def _one(records: list[dict], want: dict[str, str], what: str) -> dict:
    """The one record whose fields read as ``want``; KeyError naming ``what`` otherwise."""
    found = [r for r in records if all(str(r.get(k)) == v for k, v in want.items())]
    if len(found) != 1:
        raise KeyError(f"{len(found)} records of {what} match {want}, not one")
    return found[0]


def _difference(stat: dict, digits: int, interval: bool = True) -> str:
    """ "+0.130 [0.120, 0.139]": a signed mean and its 95% interval, with the page's minus."""
    text = f"{stat['mean']:+.{digits}f}"
    if interval:
        text += f" [{stat['ci95'][0]:.{digits}f}, {stat['ci95'][1]:.{digits}f}]"
    return text.replace("-", "−")


def pair(root: Path, figure: str, names: str, metric: str, digits: str = "3") -> str:
    """The paired difference a − b (``names``: ``a/b``) of the final ``metric`` with its 95%
    interval."""
    a, b = names.split("/")
    row = _one(_summary(root, figure)["paired"], {"a": a, "b": b, "metric": metric}, figure)
    return _difference(row["final"], int(digits))


def user_pair(
    root: Path, figure: str, names: str, user: str, metric: str, digits: str, mean_only: str = ""
) -> str:
    """A paired difference a − b (``names``: ``a/b``, ``_`` for spaces) of ``metric`` (``:``
    for spaces: ``final:regret``) for one ``user`` (``_`` for spaces) of a learners × users
    study, with its 95% interval (``mean``: the mean alone)."""
    a, b = names.replace("_", " ").split("/")
    want = {"a": a, "b": b, "user": user.replace("_", " "), "metric": metric.replace(":", " ")}
    row = _one(_summary(root, figure)["paired"], want, figure)
    return _difference(row, int(digits), interval=mean_only != "mean")


def cell(root: Path, figure: str, learner: str, user: str, key: str, digits: str = "3") -> str:
    """One cell of a learners × users study's ``matrix`` (``user`` with ``_`` for spaces):
    ``key`` (e.g. ``regret``) as mean ± SEM, or a field as it is (``regret_mean``,
    ``relevance_auc``), with ``digits`` decimals or a format spec (``.1%``); "—" where the
    study has none."""
    want = {"learner": learner, "user": user.replace("_", " ")}
    row = _one(_summary(root, figure)["matrix"], want, f"{figure}'s matrix")
    spec = f".{digits}f" if digits.isdigit() else digits
    if f"{key}_mean" in row and f"{key}_sem" in row:
        if row[f"{key}_mean"] is None:
            return "—"
        return f"{row[f'{key}_mean']:{spec}} ± {row[f'{key}_sem']:{spec}}"
    return "—" if row[key] is None else format(row[key], spec)


def find(root: Path, figure: str, path: str, where: str, key: str, spec: str = "") -> str:
    """A field of the one record, in the list at ``path`` of ``figure``'s summary, whose fields
    match ``where`` (``field=value;field=value``), formatted by ``spec``."""
    items = _summary(root, figure)
    for part in path.split("."):
        items = items[part]
    return format(_one(items, _where(where), f"{figure} {path}")[key], spec)


def minutes(root: Path, figure: str) -> str:
    """How long ``figure``'s committed run took, in whole minutes (``wall_time_s``)."""
    return f"{_summary(root, figure)['wall_time_s'] / 60:.0f}"


def workers(root: Path, figure: str) -> str:
    """Where ``figure``'s committed run ran, e.g. "2 workers"."""
    return _summary(root, figure)["executor"].rsplit(", ", 1)[-1]


def weights(root: Path, figure: str, learners: str, iterations: str) -> str:
    """Mean |θ̂ᵢ − θ*ᵢ| over runs, per weight, at each of ``iterations`` (t), one column per
    learner, from ``figure``'s ``curves.csv``."""
    names, steps = _names(learners), [int(t) for t in _names(iterations)]
    theta_star = _summary(root, figure)["settings"]["theta_star"]
    sums: dict[tuple[str, int], list] = {}
    with open(root / "results" / figure / "curves.csv", newline="") as f:
        for row in csv.DictReader(f):
            key = (row["learner"], int(row["iteration"]))
            if key[0] in names and key[1] in steps:
                gaps = [abs(float(row[f"theta_{i}"]) - w) for i, w in enumerate(theta_star)]
                sums.setdefault(key, []).append(gaps)
    missing = [f"{n} t = {t}" for n in names for t in steps if (n, t) not in sums]
    if missing:
        raise KeyError(f"{figure}/curves.csv has no {', '.join(missing)}")
    lines = ["| t | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    for t in steps:
        cells = []
        for n in names:
            runs = sums[(n, t)]
            means = [sum(r[i] for r in runs) / len(runs) for i in range(len(theta_star))]
            cells.append(", ".join(f"{m:.2f}" for m in means))
        lines.append(f"| {t} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def final_theta(root: Path, curves: str, learner: str, digits: str = "2") -> str:
    """``learner``'s θ̂ after its last correction in ``results/<curves>`` (a curves.csv), as
    "(−0.71, −0.86)"."""
    theta = None
    with open(root / "results" / curves, newline="") as f:
        for row in csv.DictReader(f):
            if row["learner"] == learner:
                weights = sorted(k for k in row if k.startswith("theta_"))
                theta = [float(row[k]) for k in weights]
    if theta is None:
        raise KeyError(f"{curves} has no learner {learner}")
    return "(" + ", ".join(f"{w:.{int(digits)}f}" for w in theta).replace("-", "−") + ")"


def aggregate(root: Path, table: str, where: str, column: str, stat: str, spec: str = "") -> str:
    """``stat`` (mean, min, max) of ``column`` over the rows of ``results/<table>`` (a CSV)
    whose fields match ``where`` (``field=value;field=value``), formatted by ``spec``."""
    want = _where(where)
    with open(root / "results" / table, newline="") as f:
        values = [
            float(r[column])
            for r in csv.DictReader(f)
            if all(r.get(k) == v for k, v in want.items())
        ]
    if not values:
        raise KeyError(f"no row of {table} matches {where}")
    reduce = {"mean": lambda v: sum(v) / len(v), "min": min, "max": max}[stat]
    return format(reduce(values), spec)


@functools.lru_cache(maxsize=32)
def _last_rows(path: str, stamp: tuple[int, int]) -> dict[tuple[str, str], dict[int, dict]]:
    """{(user, learner): {run: row}} at each pair's last correction, of the ``curves.csv`` at
    ``path``; read once per version of the file (``stamp``: its mtime and size)."""
    last: dict[tuple[str, str], dict[int, dict]] = {}
    at: dict[tuple[str, str], int] = {}
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            key, t = (r.get("user", ""), r["learner"]), int(r["iteration"])
            if t > at.get(key, -1):
                at[key], last[key] = t, {}
            if t == at[key]:
                last[key][int(r["run"])] = r
    return last


def _final_by_run(root: Path, folders: str, user: str, learner: str, metric: str) -> dict:
    """{run: ``metric`` at the last correction} of ``learner`` for ``user`` in the first of
    ``folders`` (figure folders under ``results/`` joined by ``+``) whose ``curves.csv`` has it
    (``user`` "" in a study of one person, whose curves have no ``user`` column)."""
    for folder in folders.split("+"):
        path = root / "results" / folder / "curves.csv"
        info = path.stat()
        rows = _last_rows(str(path), (info.st_mtime_ns, info.st_size)).get((user, learner))
        if rows:
            return {run: float(r[metric]) for run, r in rows.items()}
    raise KeyError(f"no {learner} for {user!r} in {folders}")


def pooled_pair(
    root: Path, studies: str, names: str, user: str, metric: str, digits: str = "3"
) -> str:
    """The mean over ``studies`` (the same people in independent studies, e.g. at other θ*:
    comma-separated, each one or more figure folders joined by ``+``) of the paired difference
    a − b (``names``: ``a/b``) of ``metric`` at the last correction for one ``user`` (``_`` for
    spaces; ``-`` for studies of one person), paired by run within each study, with a 95%
    interval: mean ± 1.96 · √(Σ SEᵢ²) / m
    over the m studies (the studies are independent; each SEᵢ over its runs)."""
    a, b = names.split("/")
    user = _user(user)
    means, variances = [], []
    for study in studies.split(","):
        first = _final_by_run(root, study, user, a, metric)
        second = _final_by_run(root, study, user, b, metric)
        if sorted(first) != sorted(second) or len(first) < 2:
            raise KeyError(f"{a} and {b} do not share two or more runs in {study}")
        d = [first[r] - second[r] for r in sorted(first)]
        mean = sum(d) / len(d)
        means.append(mean)
        variances.append(sum((x - mean) ** 2 for x in d) / (len(d) - 1) / len(d))
    mean = sum(means) / len(means)
    half = 1.96 * sum(variances) ** 0.5 / len(means)
    return _difference({"mean": mean, "ci95": (mean - half, mean + half)}, int(digits))


def _user(text: str) -> str:
    """A quote's user argument: ``_`` for spaces, ``-`` for a study of one person."""
    return "" if text == "-" else text.replace("_", " ")


def mean_ci(root: Path, folder: str, learner: str, user: str, metric: str, digits: str) -> str:
    """The mean over runs of ``learner``'s ``metric`` at the last correction in
    ``results/<folder>/curves.csv`` for ``user`` (``-``: a study of one person), with its 95%
    interval, mean ± 1.96 SEM."""
    values = list(_final_by_run(root, folder, _user(user), learner, metric).values())
    if len(values) < 2:
        raise KeyError(f"{learner} has fewer than two runs in {folder}")
    mean = sum(values) / len(values)
    sem = (sum((x - mean) ** 2 for x in values) / (len(values) - 1) / len(values)) ** 0.5
    n = int(digits)
    return f"{mean:.{n}f} [{mean - 1.96 * sem:.{n}f}, {mean + 1.96 * sem:.{n}f}]".replace("-", "−")


def _table(make: Callable[..., list[str]]) -> Callable[..., str]:
    def quote(root: Path, figure: str, *args: str) -> str:
        return "\n".join(make(_summary(root, figure), *args))

    quote.__doc__ = make.__doc__
    return quote


#: What a page may quote: name → function(root, *arguments) → text.
QUOTES: dict[str, Callable[..., str]] = {
    "headline": headline,
    "value": value,
    "minutes": minutes,
    "weights": weights,
    "final": final,
    "pair": pair,
    "user-pair": user_pair,
    "pooled-pair": pooled_pair,
    "mean-ci": mean_ci,
    "cell": cell,
    "find": find,
    "theta": final_theta,
    "aggregate": aggregate,
    "workers": workers,
    "final-table": _table(lambda s, names=None: report.final_table(s, names and _names(names))),
    "calibration-table": _table(
        lambda s, names=None: report.calibration_table(s, names and _names(names))
    ),
    "paired-table": _table(
        lambda s, pairs=None, metrics=None: report.paired_table(
            s,
            pairs and [tuple(p.split("/")) for p in _names(pairs)],
            metrics and _names(metrics),
        )
    ),
    "learners-table": _table(lambda s, names: report.learner_table(s, _names(names))),
    "matrix-table": _table(report.matrix_table),
}


class QuoteError(ValueError):
    """A quote that names no quote, or whose file or value is missing (one line)."""


def _rendered(what: str, root: Path) -> str:
    """The quote's text as it stands in a page: a table between blank lines, a number inline."""
    name, *args = what.split()
    if name not in QUOTES:
        raise QuoteError(f"quote {what!r}: no such quote (known: {', '.join(QUOTES)})")
    try:
        text = QUOTES[name](root, *args)
    except (KeyError, IndexError, TypeError, ValueError, OSError) as exc:
        detail = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        raise QuoteError(f"quote {what!r}: {detail}") from None
    return f"\n\n{text}\n\n" if "\n" in text else text


def fill(text: str, root: Path) -> str:
    """``text`` with every quote's content computed afresh from ``root/results``."""
    return PATTERN.sub(
        lambda m: f"<!-- quote {m[1]} -->{_rendered(m[1], root)}<!-- /quote -->", text
    )


def stale(text: str, root: Path) -> list[tuple[str, str, str]]:
    """(name, what the page says, what the file says) for every quote that differs."""
    found = []
    for m in PATTERN.finditer(text):
        now = _rendered(m[1], root)
        if m[2].strip() != now.strip():
            found.append((m[1], m[2].strip(), now.strip()))
    return found
