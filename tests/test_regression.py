"""Regression guard on the learning curves of figs. 4 and 5 (quick presets).

The reference curves in ``results/reference/<fig>/curves.csv`` are produced by the code itself:

    python -m corrections_sim.run fig4 --quick --out results/reference
    python -m corrections_sim.run fig5 --quick --out results/reference

(their quick presets hold the figures' own learners, the recommended robot EX-M among them,
on a plan atlas of 7 points a weight), and every registered learner on those presets:

    python -m corrections_sim.run learners fig4 --quick --out results/reference
    python -m corrections_sim.run learners fig5 --quick --out results/reference

Both are checked from one run of every learner a figure (a learner's runs do not depend on
which others run beside it; the two references agree to the byte on the figure's learners).

Tolerance: a run is deterministic (same seed, same bytes, any number of workers), so on one
machine the curves repeat exactly. Between machines, floating-point differences in IPOPT and
MUMPS can send a single planner solve to a neighbouring local optimum; one environment of 48
then changes the summed regret by about one unit in 35–180, i.e. < 1% of a mean over 4 runs.
We allow 3% on regret and 1% on the estimate error: several such flips pass, a change of the
learners, the user or the planner does not.
"""

from __future__ import annotations

import csv
import dataclasses
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from corrections_sim.figures import every_learner, learning_study
from corrections_sim.study import analysis, runner

REFERENCE = Path(__file__).resolve().parents[1] / "results" / "reference"
TOLERANCE = {"estimate_error": 0.01, "regret": 0.03}
# EX-M ends near zero regret (0.43 over 48 environments, mean of 4 runs): one environment's
# plan at a neighbouring local optimum on another CPU moves that by more than 3%, so the
# absolute part allows about a tenth of such a flip.
EX_M_ATOL = {"regret": 0.1, "estimate_error": 0.005}


def _mean_curves(rows: list[dict], learner: str, key: str) -> np.ndarray:
    mine = [r for r in rows if r["learner"] == learner]
    iterations = sorted({int(r["iteration"]) for r in mine})
    return np.array(
        [np.mean([float(r[key]) for r in mine if int(r["iteration"]) == t]) for t in iterations]
    )


def _auc(records: list[dict], learner: str, key: str) -> float:
    """Area under the mean curve (sum over iterations of the mean over runs)."""
    return float(np.sum(_mean_curves(records, learner, key)))


class QuickFigure:
    """The checks of one learning figure's quick preset; a subclass per figure (one class a
    scheduling group: the suite's workers run fig. 4 and fig. 5 side by side).

    Every registered learner runs once on the preset (``run learners <figure> --quick``), and
    both references are checked from that one run: the figure's own learners against
    ``results/reference/<figure>`` (``run <figure> --quick``), every learner against
    ``results/reference/learners/<figure>``. A learner's runs are the same whichever others
    run beside it (:func:`~corrections_sim.study.runner.run_key`; the two committed references
    agree to the byte on the figure's learners), so running the figure's learners a second
    time would check nothing more.
    """

    figure: str
    #: Absolute tolerance on top of :data:`TOLERANCE`'s relative one, per key.
    atol: dict = EX_M_ATOL

    @pytest.fixture(scope="class")
    @classmethod
    def quick_run(cls):
        """(the figure's own settings, every learner's settings, every learner's result)."""
        own = learning_study.load_settings(cls.figure, quick=True, overrides={})
        every = {"learners": every_learner.every_learner(atlas=True)[0]}
        settings = learning_study.load_settings(cls.figure, quick=True, overrides=every)
        assert set(own.study.learners) <= set(settings.study.learners)
        # One worker thread: the same code path as the process pool, without process start-up.
        # The regret of the mean estimate (mean_estimate.csv) is not among the checks.
        with ThreadPoolExecutor(max_workers=1) as executor:
            result = runner.run(settings, executor, mean_estimate=False)
        return own, settings, result

    def _match(self, records: list[dict], learners, folder: Path) -> None:
        with open(folder / self.figure / "curves.csv", newline="") as fh:
            reference = list(csv.DictReader(fh))
        mine = [r for r in records if r["learner"] in set(learners)]
        assert len(mine) == len(reference)
        assert {r["learner"] for r in reference} == set(learners)
        for learner in learners:
            for key, rtol in TOLERANCE.items():
                now = _mean_curves(mine, learner, key)
                ref = _mean_curves(reference, learner, key)
                np.testing.assert_allclose(
                    now,
                    ref,
                    rtol=rtol,
                    atol=self.atol.get(key, 0.0),
                    err_msg=f"{self.figure} {learner} {key}",
                )

    def test_quick_curves_match_the_reference(self, quick_run):
        """The figure's learners against ``results/reference/<figure>/curves.csv``."""
        own, _, result = quick_run
        self._match(result.records, own.study.learners, REFERENCE)

    def test_every_learners_quick_curves_match_the_reference(self, quick_run):
        """Every registered learner against ``results/reference/learners/<figure>``, so that
        the learners the figures no longer show are guarded as they were."""
        _, settings, result = quick_run
        self._match(result.records, settings.study.learners, REFERENCE / "learners")

    def test_every_learner_improves_and_no_solve_fails(self, quick_run):
        _, settings, result = quick_run
        assert all(r["regret_failures"] == 0 for r in result.records)
        assert not any(r["update_skipped"] for r in result.records)
        for learner in settings.study.learners:
            for key in ("estimate_error", "regret"):
                curve = _mean_curves(result.records, learner, key)
                assert curve[-1] < curve[0], f"{self.figure} {learner} {key} did not fall: {curve}"


class PaperQuickFigure(QuickFigure):
    """A learning figure's quick preset: its own learners (the paper's, KF-C and AL-C, and
    the recommended robot) and every other registered learner."""

    def test_active_learning_shrinks_the_covariance_fastest(self, quick_run):
        """What AL optimizes, eq. (A1): its final P is smaller than the random-environment
        KF's.

        In fig. 4 this is also why the paper's ordering does not reproduce here (see
        docs/results.md): AL's P collapses so fast that its later gains vanish, and KF and PP
        end within a few percent of each other, so no ordering of fig. 4 is asserted.
        """
        own, _, result = quick_run
        last = own.study.iterations

        def trace(learner: str) -> float:
            rows = [r for r in result.records if r["learner"] == learner and r["iteration"] == last]
            return float(np.mean([sum(r[f"cov_{i}{i}"] for i in range(own.study.k)) for r in rows]))

        assert trace("AL") < trace("KF")


class TestFig4(PaperQuickFigure):
    figure = "fig4"

    def test_kf_c_is_calibrated_where_the_papers_kf_is_not(self, quick_run):
        """Issue 9's mechanism: the paper's observation model, Φ(ξ*(θ)), expects a correction
        to show the whole intended change, the biased user shows a fraction, so KF's P shrinks
        too fast and its mean NEES leaves the χ² band of a calibrated mean; KF-C predicts the
        correction itself, and its mean NEES stays inside the band at every iteration."""
        own, _, result = quick_run
        stats = analysis.summarize(own, _only(result, own.study.learners))["calibration"]
        low, high = stats["KF"]["band"]
        assert stats["KF"]["mean_nees"][-1] > high, stats["KF"]["mean_nees"]
        kf_c = stats["KF-C"]
        assert kf_c["inside_band"] == 1.0, (kf_c["mean_nees"], kf_c["band"])
        assert kf_c["coverage_2sigma_mean"] > stats["KF"]["coverage_2sigma_mean"]

    def test_the_recommended_robot_learns_the_papers_person_best(self, quick_run):
        """Measured: after 4 corrections EX-M's error is 0.137 against EX-CL's 0.614 and
        EX-C's 0.694 (4 runs), the best of the other 20 learners' 0.614, and it holds the
        paper's model, the worst waypoint moved all the way, at p = 0.95 (each of its six
        models began at 1/6)."""
        _, settings, result = quick_run
        last = settings.study.iterations
        final = {
            name: _mean_curves(result.records, name, "estimate_error")[-1]
            for name in settings.study.learners
        }
        others = min(v for name, v in final.items() if name != "EX-M")
        assert final["EX-M"] < 0.5 * others, final
        rows = [r for r in result.records if r["learner"] == "EX-M" and r["iteration"] == last]
        assert np.mean([r["model_waypoint"] for r in rows]) > 0.8


class TestFig5(PaperQuickFigure):
    figure = "fig5"

    def test_paper_claims_hold_active_learning_best_and_kalman_below_perceptron(self, quick_run):
        """Paper §6, fig. 5: KF learns faster than PP, and AL fastest, in error and regret."""
        _, _, result = quick_run
        for key in ("estimate_error", "regret"):
            pp, kf, al = (_auc(result.records, name, key) for name in ("PP", "KF", "AL"))
            assert al < kf < pp, f"{key}: AUC AL {al:.3f}, KF {kf:.3f}, PP {pp:.3f}"


def test_every_learning_figure_has_its_class():
    classes = PaperQuickFigure.__subclasses__()
    assert {c.figure for c in classes} == set(learning_study.FIGURES)


def _only(result: runner.FigureResult, learners) -> runner.FigureResult:
    """``result`` with the records of ``learners`` only (as the figure's own run holds)."""
    keep = set(learners)
    records = [r for r in result.records if r["learner"] in keep]
    return dataclasses.replace(result, records=records)


def _check_matrix(
    figure: str,
    keys: dict[str, float],
    *,
    labels: bool = False,
    column_keys: tuple[str, ...] | None = None,
    written=None,
) -> int:
    """A matrix figure's quick preset against ``results/reference/<figure>``: per column
    (person) and learner, the mean curve of every key the reference has; the ``relevant``
    labels exactly with ``labels``. ``written(column, records)``: the records as the figure
    writes them to curves.csv, where it changes them. Returns how many curves were
    compared."""
    from corrections_sim.figures import robustness

    more = {} if column_keys is None else {"column_keys": column_keys}
    settings = robustness.load_settings(quick=True, figure=figure, **more)
    with open(REFERENCE / figure / "curves.csv", newline="") as fh:
        reference = list(csv.DictReader(fh))
    with ThreadPoolExecutor(max_workers=1) as executor:
        results = robustness.run(settings, executor)
    checked = 0
    for column, result in zip(settings.columns, results, strict=True):
        ref = [r for r in reference if r["user"] == column.label]
        records = result.records if written is None else written(column, result.records)
        assert len(records) == len(ref)
        if labels:
            now = [r.get("relevant") for r in records]
            assert now == [None if r["relevant"] == "" else float(r["relevant"]) for r in ref]
        for learner in column.settings.study.learners:
            for key, rtol in keys.items():
                rows = [r for r in ref if r["learner"] == learner and r.get(key) not in (None, "")]
                if not rows:
                    continue
                now = [r for r in records if r.get(key) is not None]
                np.testing.assert_allclose(
                    _mean_curves(now, learner, key),
                    _mean_curves(rows, learner, key),
                    rtol=rtol,
                    atol=1e-6,
                    err_msg=f"{figure} {column.label} {learner} {key}",
                )
                checked += 1
    return checked


def test_quick_physical_curves_match_the_reference():
    """The physical study's quick preset (``run physical --quick --out results/reference``):
    both columns, error, regret and the executed regret online and kept."""
    keys = {**TOLERANCE, "executed_regret": 0.03, "executed_regret_kept": 0.03}
    checked = _check_matrix("physical", keys)
    assert checked == 2 * 4 * 2 + 4 * 2  # both columns' error and regret, the pushes' regrets


def test_quick_relevance_curves_match_the_reference():
    """The relevance study's quick preset (``run relevance --quick --out results/reference``):
    every person's error and regret, KF-CR's, PP-R's and KF-CRP's β̂ per correction (its mean
    per iteration), and the labels exactly."""
    checked = _check_matrix("relevance", {**TOLERANCE, "relevance": 0.03}, labels=True)
    assert checked == 4 * 9 * 2 + 4 * 3  # every person's error and regret, three learners' β̂


def test_quick_ferl_curves_match_the_reference():
    """The FERL study's quick preset (``run ferl --quick --out results/reference``): every
    person's error on the features every robot knows (``known_error``, the study's one
    error) and regret, and for KF-CRX whether it asked and expanded (exactly) and the learnt
    feature's Spearman ρ against the person's."""
    from corrections_sim.figures import ferl

    keys = {
        ferl.KNOWN_ERROR: TOLERANCE["estimate_error"],
        "regret": TOLERANCE["regret"],
        "asked": 0.0,
        "expanded": 0.0,
        "learnt_spearman": 0.02,
    }
    k0 = len(ferl.FerlFigure().load(quick=True, overrides={}).columns[0].settings.features)
    checked = _check_matrix(
        "ferl",
        keys,
        column_keys=ferl.COLUMN_KEYS,
        written=lambda column, records: ferl.with_known_error(column, records, k0),
    )
    # Five people x three learners and the four upper bounds: error and regret; KF-CRX's
    # asking for the three people it asks (who mind only `human`, only the tilt, and in one
    # run of two who also minds `human`), its expanding and the learnt ρ where it expanded.
    assert checked == (5 * 3 + 4) * 2 + 3 * 3
