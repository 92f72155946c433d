"""Learning the feature the robot lacks (FERL: Bobu, Wiggert, Tomlin & Dragan, HRI 2021 and
IJRR 2022): a robot that asks for feature traces when a person's corrections are not
explained, learns a feature from them and its weight from the corrections that follow.

The columns of ``experiments/ferl.toml`` are people, as in the relevance figure: the paper's
biased user (who should never make the robot ask), a person who also minds the coffee coming
close to them (`human`, weight −2) and one who minds only that (−5); and the last two again
with a robot that knows `human` from the start (a column may set ``features`` and
``learners``): the upper bound. Rows are learners: KF-C, KF-CRP (which notices) and KF-CRX
(which notices and asks,
:meth:`~corrections_sim.learning.relevance.expansion.ExpandingRelevanceKalman.expand`).

Besides the study, the quality of a learnt feature against the number of traces and the
teacher's noise: Spearman ρ between the learnt and the true `human` on 10,000 random
reachable configurations (FERL's measure), over seeds.

Files: ``matrix.csv`` (per person and learner: final regret of the person's whole objective
and ``known_error``, mean ± SEM; how often the learner asked and expanded, when,
the learnt feature's Spearman ρ and R² against the person's, and its weight against the
person's weight mapped through the best affine fit), ``paired.csv`` (KF-CRX − KF-C and
KF-CRX − the upper bound, paired by run: final regret and known error), ``curves.csv``
(every record, its ``known_error`` in place of ``estimate_error``: one error for every robot,
see :data:`KNOWN_ERROR`),
``quality.csv`` (one row per traces × teacher noise × seed) and the plots ``ferl.png``
(regret and error over corrections per person) and ``ferl-quality.png``.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from corrections_sim.figures import robustness
from corrections_sim.figures.registry import register
from corrections_sim.learnt.training import learn, quality
from corrections_sim.learnt.training import register as register_learnt
from corrections_sim.metrics import estimate_error, mean_sem
from corrections_sim.study import analysis
from corrections_sim.study.runner import FigureResult

FIGURE = "ferl"
#: A column is a person, and may give the robot other features and learners (the upper
#: bound: a robot that knows the person's feature from the start), and plan without the
#: study's atlas (``atlas = false``: the upper bound's features have none), its person then
#: planned as the other columns' (``person_restarts``).
COLUMN_KEYS = (*robustness.COLUMN_KEYS, "features", "learners", "atlas", "person_restarts")
#: The quality sweep: traces per feature, the teacher's noise (relative to the study's
#: teacher: none, as set, twice), seeds per cell; the quick preset's in brackets.
TRACES, QUICK_TRACES = (1, 2, 5, 10, 20), (2, 10)
NOISE_SCALES = {"noiseless": 0.0, "default": 1.0, "double": 2.0}
SEEDS, QUICK_SEEDS = 10, 2
#: The learner that expands, what it is compared with, and the upper bound's.
EXPANDING, BASELINE = "KF-CRX", "KF-C"


def _person(column) -> tuple[float, ...]:
    s = column.settings
    return tuple(s.study.user_theta or s.study.theta_star)


def _knows_all(column) -> bool:
    s = column.settings
    return not s.user_features or set(s.user_features) <= set(s.features)


def known_error(column, records: Sequence[dict], k0: int) -> dict[str, np.ndarray]:
    """learner -> ``known_error`` (:func:`with_known_error`), (runs, T+1)."""
    out: dict[str, dict[int, list]] = {}
    for r in with_known_error(column, records, k0):
        out.setdefault(r["learner"], {}).setdefault(r["run"], []).append(
            (r["iteration"], r[KNOWN_ERROR])
        )
    return {
        name: np.array([[e for _, e in sorted(v)] for _, v in sorted(runs.items())])
        for name, runs in out.items()
    }


#: The one error every file of the study reports, for every robot alike: ‖θ̂ − θ*‖₁ on the
#: first k0 features, those every column's robot knows (laptop and table). A run's own
#: ``estimate_error`` is over its robot's features, which differ by column (the upper bound's
#: counts `human`), so the study's files carry this column instead.
KNOWN_ERROR = "known_error"


def with_known_error(column, records: Sequence[dict], k0: int) -> list[dict]:
    """``records`` with :data:`KNOWN_ERROR` in place of their ``estimate_error``."""
    s = column.settings
    star = np.array(s.study.person()[:k0] if not s.user_features else _on(s, k0), float)
    out = []
    for r in records:
        theta = np.array([float(r[f"theta_{i}"]) for i in range(k0)])
        rec = {key: value for key, value in r.items() if key != "estimate_error"}
        out.append(rec | {KNOWN_ERROR: estimate_error(theta, star)})
    return out


def _on(settings, k0: int) -> list[float]:
    """The person's weights on the first ``k0`` of the robot's features."""
    names = settings.features[:k0]
    return [settings.study.person()[settings.user_features.index(n)] for n in names]


def matrix(settings, results: Sequence[FigureResult], k0: int) -> list[dict]:
    """Per person and learner: final regret and error on the study's features (mean, SEM),
    and for a learner that can expand: how often it asked and expanded, at which correction,
    the learnt feature's quality and its weight's error against the person's mapped one."""
    rows = []
    for column, result in zip(settings.columns, results, strict=True):
        data = analysis.curves(column.settings, result.records)
        errors = known_error(column, result.records, k0)
        for learner in column.settings.study.learners:
            regret = data[learner]["regret"][:, -1]
            error = errors[learner][:, -1]
            row = {"user": column.label, "learner": learner, "runs": int(regret.size)}
            row["regret_mean"], row["regret_sem"] = _ms(regret)
            row[f"{KNOWN_ERROR}_mean"], row[f"{KNOWN_ERROR}_sem"] = _ms(error)
            final = [
                r
                for r in result.records
                if r["learner"] == learner and r["iteration"] == column.settings.study.iterations
            ]
            if any("asked" in r for r in final):
                asked = np.array([float(r.get("asked") or 0.0) for r in final])
                expanded = np.array([float(r.get("expanded") or 0.0) for r in final])
                row |= {"asked": float(asked.mean()), "expanded": float(expanded.mean())}
                grown = [r for r in final if r.get("expanded")]
                if grown:
                    got = {
                        key: np.array([float(r[key]) for r in grown])
                        for key in ("learnt_weight", "learnt_weight_target", "expanded_at")
                        + ("learnt_spearman", "learnt_r2")
                    }
                    weight = got["learnt_weight"] - got["learnt_weight_target"]
                    row |= {
                        "expanded_at": float(np.mean(got["expanded_at"])),
                        "spearman": float(np.mean(got["learnt_spearman"])),
                        "r2": float(np.mean(got["learnt_r2"])),
                        "weight_error": float(np.mean(np.abs(weight))),
                    }
            rows.append(row)
    return rows


def _ms(values: np.ndarray) -> tuple[float, float]:
    m, s = mean_sem(values[:, None])
    return float(np.ravel(m)[0]), float(np.ravel(s)[0])


def paired(settings, results: Sequence[FigureResult], k0: int) -> list[dict]:
    """Paired 95% intervals of KF-CRX minus KF-C (same person, same runs' draws) and minus
    the upper bound (KF-C of the column where the robot knows the person's feature): final
    regret and error on the study's features."""
    out = []
    final = {}
    for column, result in zip(settings.columns, results, strict=True):
        data = analysis.curves(column.settings, result.records)
        errors = known_error(column, result.records, k0)
        for learner in column.settings.study.learners:
            final[(column.label, learner)] = (
                data[learner]["regret"][:, -1],
                errors[learner][:, -1],
            )
    for column in settings.columns:
        if EXPANDING not in column.settings.study.learners:
            continue
        rivals = [(BASELINE, column.label)]
        bound = _bound(settings, column)
        if bound is not None:
            rivals.append((BASELINE, bound.label))
        for rival, where in rivals:
            if (where, rival) not in final:
                continue
            a, b = final[(column.label, EXPANDING)], final[(where, rival)]
            if a[0].shape != b[0].shape:
                continue
            for i, metric in enumerate(("final regret", f"final {KNOWN_ERROR}")):
                out.append(
                    {
                        "user": column.label,
                        "a": EXPANDING,
                        "b": rival if where == column.label else f"{rival} ({where})",
                        "metric": metric,
                    }
                    | analysis._mean_ci(a[i] - b[i])
                )
    return out


def _bound(settings, column):
    """The column where the robot knows the features this column's person minds (the same
    weights on the same features)."""
    if _knows_all(column):
        return None
    theirs = column.settings.user_features
    for other in settings.columns:
        if (
            other is not column
            and _knows_all(other)
            and _person(other) == _person(column)
            and other.settings.features == theirs
        ):
            return other
    return None


def _lacked(column) -> str:
    """The features this column's person minds that its robot lacks, for a label."""
    s = column.settings
    return ", ".join(n for n in s.user_features if n not in s.features)


def quality_sweep(settings, *, quick: bool) -> list[dict]:
    """Spearman ρ and R² of features learnt from N traces against the true one, per feature
    the study's people mind that the robot lacks, teacher noise and seed, in the study's first
    environment (each cell seeded from the study's seed, so the sweep is the same on every
    run)."""
    first = settings.columns[0].settings
    env = first.envs()[0]
    base = first.study.teacher
    rows = []
    for f, feature in enumerate(_taught(settings)):
        for n in QUICK_TRACES if quick else TRACES:
            for j, (label, scale) in enumerate(NOISE_SCALES.items()):
                teacher = replace(
                    base, path_noise=base.path_noise * scale, label_noise=base.label_noise * scale
                )
                for seed in range(QUICK_SEEDS if quick else SEEDS):
                    key = [first.study.seed, n, j, seed] + ([f] if f else [])
                    rng = np.random.default_rng(key)
                    traces = teacher.traces(feature, n, env, rng)
                    start = time.process_time()
                    learnt = learn(traces, env, rng)
                    seconds = time.process_time() - start
                    register_learnt(learnt)
                    q = quality(learnt.name, feature, env)
                    rows.append(
                        {
                            "feature": feature,
                            "traces": n,
                            "noise": label,
                            "path_noise": teacher.path_noise,
                            "label_noise": teacher.label_noise,
                            "seed": seed,
                            "spearman": q.spearman,
                            "r2": q.r2,
                            "train_seconds": seconds,
                        }
                    )
    return rows


def _taught(settings) -> tuple[str, ...]:
    """The features the people of the figure mind that the robot lacks, in column order."""
    out: dict[str, None] = {}
    for column in settings.columns:
        s = column.settings
        out |= {name: None for name in s.user_features if name not in s.features}
    if not out:
        raise ValueError(f"{FIGURE}: no column's person minds a feature the robot lacks")
    return tuple(out)


def write(settings, results: Sequence[FigureResult], folder: Path, sweep: list[dict]) -> dict:
    """matrix.csv, paired.csv, curves.csv, quality.csv and the plots; the summary's fields."""
    from corrections_sim.figures.output import write_csv

    k0 = len(settings.columns[0].settings.features)
    rows = matrix(settings, results, k0)
    pairs = paired(settings, results, k0)
    written = [
        replace(result, records=with_known_error(column, result.records, k0))
        for column, result in zip(settings.columns, results, strict=True)
    ]
    summary = robustness.write_matrix(settings, written, rows, folder, pairs)
    write_csv(folder / "quality.csv", sweep)
    title = robustness.title(settings, FIGURE)
    curves = {}
    for column, result in zip(settings.columns, results, strict=True):
        data = analysis.curves(column.settings, result.records)
        errors = known_error(column, result.records, k0)
        curves[column.label] = {
            learner: {"regret": data[learner]["regret"], "error": errors[learner]}
            for learner in column.settings.study.learners
        }
    people = [c.label for c in settings.columns if not _knows_all(c) or c is settings.columns[0]]
    bounds = {
        c.label: (b.label, _lacked(c))
        for c in settings.columns
        if (b := _bound(settings, c)) is not None
    }
    plot_ferl(curves, people, bounds, title, [folder / f"{FIGURE}.png", folder / f"{FIGURE}.pdf"])
    plot_ferl_quality(sweep, title, [folder / f"{FIGURE}-quality.png"])
    table: dict[str, dict[str, list]] = {}
    for row in sweep:
        cell = table.setdefault(f"{row['feature']} {row['noise']} x{row['traces']}", {})
        for measure in ("spearman", "r2"):
            cell.setdefault(measure, []).append(row[measure])
    return summary | {
        "quality": {
            key: {
                measure: {"mean": float(np.mean(v)), "min": float(np.min(v))}
                for measure, v in cell.items()
            }
            for key, cell in table.items()
        },
        "train_seconds_mean": float(np.mean([r["train_seconds"] for r in sweep])),
    }


@dataclass(frozen=True)
class FerlFigure(robustness.RobustnessFigure):
    """The FERL study as a registered figure: people as columns (with the upper bound's),
    cached per column; the quality sweep is recomputed with every write (≈ 1 min)."""

    name: str = FIGURE
    help: str = "beyond the paper: a robot that learns the feature it lacks (FERL)"
    in_all: bool = False

    def load(self, *, quick: bool, overrides: Mapping[str, Any]) -> FerlSettings:
        settings = robustness.load_settings(
            quick=quick, overrides=dict(overrides), figure=FIGURE, column_keys=COLUMN_KEYS
        )
        return FerlSettings(columns=settings.columns, quick=quick)

    def write(self, settings: FerlSettings, result: list[FigureResult], folder: Path) -> dict:
        sweep = quality_sweep(settings, quick=settings.quick)
        return write(settings, result, folder, sweep)


@dataclass(frozen=True)
class FerlSettings(robustness.RobustnessSettings):
    """The columns, and whether the quality sweep is the quick preset's."""

    quick: bool = False


register(FerlFigure())


def plot_ferl(curves: dict, people: list[str], bounds: dict, title: str, paths) -> None:
    """The FERL figure: per person (columns), the regret of their whole objective (top) and
    the error on the robot's own features (bottom) over corrections, mean ± SEM per learner,
    and the upper bound (KF-C of the column where the robot knows their feature) dashed grey.

    Args:
        curves: column label -> learner -> {"regret", "error"} arrays (runs, T + 1).
        people: the columns to draw, in order.
        bounds: column label -> the label of its upper bound's column and the features
            that robot knows and this one lacks.
        paths: files to write.
    """
    from corrections_sim.figures.style import learner_style, plt, save_and_close
    from corrections_sim.metrics import mean_sem

    fig, axes = plt.subplots(2, len(people), figsize=(5.0 * len(people), 7.4), squeeze=False)
    for j, person in enumerate(people):
        lines = dict(curves[person])
        bound = None
        if person in bounds:
            label, lacked = bounds[person]
            bound = f"KF-C, knows {lacked}"
            lines[bound] = curves[label]["KF-C"]
        for i, metric in enumerate(("regret", "error")):
            ax = axes[i, j]
            for name, data in lines.items():
                values = data[metric]
                t = np.arange(values.shape[1])
                mean, sem = mean_sem(values)
                if name == bound:
                    colour, style = "0.45", "--"
                else:
                    colour, style = learner_style(name)
                ax.plot(t, mean, color=colour, ls=style, lw=1.4, label=name)
                ax.fill_between(t, mean - sem, mean + sem, color=colour, alpha=0.15, lw=0)
            ax.set_xlabel("corrections t")
            if i == 0:
                ax.set_title(person, fontsize=10)
                ax.set_ylabel("regret of the person's objective")
            else:
                ax.set_ylabel("error ‖θ̂ − θ*‖₁ on laptop, table")
            ax.grid(alpha=0.3)
        axes[0, j].legend(fontsize=8)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    save_and_close(fig, paths, dpi=120)


def plot_ferl_quality(rows: Sequence[dict], title: str, paths) -> None:
    """A learnt feature against the true one, against the number of traces, per teacher
    noise (mean ± SEM over seeds): Spearman ρ (FERL's measure, top) and the R² of the best
    affine fit (its shape, bottom), a column per feature, with the issue's targets."""
    from corrections_sim.figures.style import plt, save_and_close

    features = list(dict.fromkeys(r["feature"] for r in rows))
    fig, axes = plt.subplots(
        2, len(features), figsize=(4.2 * len(features) + 1.0, 7.2), squeeze=False, sharex=True
    )
    measures = (
        ("spearman", "Spearman ρ, learnt vs true", (0.9,)),
        ("r2", "R², best affine fit of learnt to true", (0.6,)),
    )
    counts = sorted({r["traces"] for r in rows})
    for c, feature in enumerate(features):
        for m, (key, label, targets) in enumerate(measures):
            ax = axes[m, c]
            for noise in dict.fromkeys(r["noise"] for r in rows):
                mine = [r for r in rows if r["noise"] == noise and r["feature"] == feature]
                values = [np.array([r[key] for r in mine if r["traces"] == n]) for n in counts]
                mean = [v.mean() for v in values]
                sem = [v.std(ddof=1) / np.sqrt(v.size) if v.size > 1 else 0.0 for v in values]
                ax.errorbar(
                    counts, mean, yerr=sem, marker="o", capsize=3, label=f"teacher: {noise}"
                )
            for level in targets:
                ax.axhline(level, color="0.6", lw=0.8, ls=":")
            ax.set_xscale("log")
            ax.set_xticks(counts, [str(n) for n in counts])
            ax.minorticks_off()
            ax.set_ylim(0.0, 1.0)
            ax.grid(alpha=0.3)
            if c == 0:
                ax.set_ylabel(label)
            if m == 0:
                ax.set_title(f"the missing feature: {feature}", fontsize=10)
            else:
                ax.set_xlabel("feature traces")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(f"{title}\n(10,000 reachable configurations; dotted: the targets)", fontsize=9)
    fig.tight_layout()
    save_and_close(fig, paths, dpi=130)
