"""``run learners fig4`` (or ``fig5``, or any study file): every registered learner on one
learning figure's settings, in its own folder (``results/learners/<name>/``).

Figs. 4 and 5 show the paper's learners, the correction-aware ones and the robot we
recommend (at most six curves, readable); every other learner lives here, drawn by family
(:func:`corrections_sim.figures.learning_plot.plot_every_learner`), beside a table of what
each is for (its ``question``) and where it ends (``table.csv``). The runs are the study's own:
a learner's run depends on the settings and its own seed stream, not on which learners run
beside it, so the six of fig. 4 are here with the same numbers.
"""

from __future__ import annotations

import csv
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from corrections_sim.figures import learning_study
from corrections_sim.figures.learning_study import OPTIONS, LearningStudy
from corrections_sim.figures.presets import EXPERIMENTS_DIR
from corrections_sim.figures.registry import register
from corrections_sim.study import schema
from corrections_sim.study.runner import FigureResult
from corrections_sim.study.settings import FigureSettings

#: The folder every setting's figure goes in, under the output folder.
FOLDER = "learners"


def every_learner(atlas: bool) -> tuple[list[str], list[str]]:
    """(the registered learners that run on a study, those left out): a learner that reads
    the plan atlas is left out of a study without one."""
    from corrections_sim.learning.base import LEARNERS

    kept = [n for n, cls in LEARNERS.items() if atlas or not cls.needs_atlas]
    return kept, [n for n in LEARNERS if n not in kept]


@dataclass(frozen=True)
class EveryLearner(LearningStudy):
    """The registered figure ``learners`` (see the module)."""

    file: str = "SETTING"

    @property
    def options(self) -> tuple[str, ...]:
        # Every learner runs: --learners would make it another study (run study, or fig4).
        return ("study_file", *(o for o in OPTIONS if o != "learners"))

    @property
    def in_all(self) -> bool:
        return False

    @property
    def option_help(self) -> dict[str, str]:
        return {
            "study_file": "fig4 or fig5 (their study files), or a study file: every registered "
            "learner on its settings"
        }

    def load(self, *, quick: bool, overrides: Mapping[str, Any]) -> FigureSettings:
        overrides = dict(overrides)
        given = overrides.pop("study_file", None)
        if not given:
            raise ValueError(
                "learners: name the settings, e.g. run learners fig4 (or fig5, or a study file)"
            )
        if given in learning_study.FIGURES:
            path, name = EXPERIMENTS_DIR / f"{given}.toml", given
        else:
            path = Path(given)
            name = path.stem
            if not path.is_file():
                raise ValueError(
                    f"learners {given}: neither {' nor '.join(learning_study.FIGURES)} nor a "
                    "study file"
                )
        try:
            first = schema.load_study(path, name=name, quick=quick, overrides=overrides)
            kept, _ = every_learner(first.study.atlas is not None)
            overrides["learners"] = kept
            settings = schema.load_study(path, name=name, quick=quick, overrides=overrides)
        except ValueError as exc:
            raise ValueError(f"{given}: {exc}") from None
        return settings

    def folder(self, settings: FigureSettings) -> str:
        return f"{FOLDER}/{settings.name}"

    def write(self, settings: FigureSettings, result: FigureResult, folder: Path) -> dict:
        from corrections_sim.figures.learning_plot import plot_every_learner

        fields = learning_study.write(
            settings,
            result,
            folder,
            FOLDER,
            plot=plot_every_learner,
            heading=f"every learner on {settings.name}'s settings",
        )
        _, left_out = every_learner(settings.study.atlas is not None)
        rows = table(fields)
        with open(folder / "table.csv", "w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=list(rows[0]) if rows else ["learner"])
            writer.writeheader()
            writer.writerows(rows)
        return {**fields, "left_out": left_out}


def _blank(value):
    """A number as it is, or an empty cell for none (a single run's SEM, no covariance)."""
    return "" if value is None else value


def table(fields: Mapping[str, Any]) -> list[dict]:
    """One row a learner: its family, the question it answers, its final estimate error and
    regret (mean ± SEM over runs) and its final mean NEES (none without a covariance)."""
    from corrections_sim.figures.learning_plot import family
    from corrections_sim.learning.base import LEARNERS

    rows = []
    for name, final in fields["final"].items():
        calibration = fields["calibration"].get(name)
        nees = calibration["mean_nees"][-1] if calibration else None
        rows.append(
            {
                "learner": name,
                "family": family(name),
                "runs": final["runs"],
                "estimate_error": final["estimate_error"]["mean"],
                "estimate_error_sem": _blank(final["estimate_error"]["sem"]),
                "regret": final["regret"]["mean"],
                "regret_sem": _blank(final["regret"]["sem"]),
                "mean_nees": _blank(nees),
                "question": LEARNERS[name].question if name in LEARNERS else "",
            }
        )
    return rows


register(
    EveryLearner(
        "learners",
        "every registered learner on fig. 4's or fig. 5's settings (or a study file's), by family",
    )
)
