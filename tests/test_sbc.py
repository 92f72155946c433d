"""Simulation-based calibration: draws from an exact posterior within its cells, the rank
test on a problem whose posterior is known, the people drawn from EX-M's prior, and the
command (files, resume, bad input). The statistic at paper scale is ``run sbc``'s, not a
test's."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from corrections_sim.cli import main as cli
from corrections_sim.figures import sbc as figure
from corrections_sim.learning.exact import bayes as ref
from corrections_sim.learning.exact.cells import Cells, cell_moments
from corrections_sim.learning.exact.draws import cell_draws, density_at, leaf_masses
from corrections_sim.study import sbc

MEAN = np.array([0.3, -0.4])
COV = np.array([[0.2, 0.1], [0.1, 0.15]])


def _refined(mean, cov, resolution=1.0, lows=(-3.0, -3.0), highs=(3.0, 3.0)):
    """A Gaussian's log density on cells refined as an exact learner refines its own."""
    inverse = np.linalg.inv(cov)

    def log_density(cells):
        d = cells.thetas() - mean
        return -0.5 * np.einsum("ni,ij,nj->n", d, inverse, d)

    cells = Cells.base(lows, highs, (7, 7), 4)
    refine = ref.Refinement(resolution=resolution)
    while (finer := refine.finer(cells, log_density(cells))) is not None:
        cells = finer
    return cells, log_density(cells)


def test_draws_within_the_cells_have_the_learners_mean_and_a_little_more_variance():
    """The draws come from the multilinear interpolant the trapezoid rule integrates: their
    mean is the learner's; their variance exceeds the learner's trapezoid moments by the
    cells' own spread (5% and 7% here, at one node an sd), the figure's docstring's claim."""
    cells, log_d = _refined(MEAN, COV)
    mean, cov = ref.moments(cells.thetas(), ref.posterior(log_d, cells.coefficients))
    draws = cell_draws(cells, log_d, 200_000, np.random.default_rng(0))
    se = np.sqrt(np.diag(cov) / len(draws))
    assert np.all(np.abs(draws.mean(axis=0) - mean) < 4 * se)
    ratio = np.diag(np.cov(draws.T)) / np.diag(cov)
    assert np.all(ratio > 1.0) and np.all(ratio < 1.1)
    assert leaf_masses(cells, log_d).sum() == pytest.approx(1.0)
    # The same draws from the same generator; every draw inside the box.
    again = cell_draws(cells, log_d, 200_000, np.random.default_rng(0))
    assert np.array_equal(draws, again)
    assert np.all((draws >= -3.0) & (draws <= 3.0))


def test_the_cells_moments_are_their_draws_in_closed_form():
    """cell_moments is the draws' mean and covariance (within their sampling error), and its
    second moment about the trapezoid mean is that covariance plus the means' gap squared."""
    cells, log_d = _refined(MEAN, COV)
    mean, cov = cell_moments(cells, log_d)
    draws = cell_draws(cells, log_d, 400_000, np.random.default_rng(1))
    se = np.sqrt(np.diag(cov) / len(draws))
    assert np.all(np.abs(draws.mean(axis=0) - mean) < 4 * se)
    assert np.allclose(np.cov(draws.T), cov, rtol=0.01, atol=0.01 * np.max(np.diag(cov)))
    node_mean, node_cov = ref.moments(cells.thetas(), ref.posterior(log_d, cells.coefficients))
    _, about = cell_moments(cells, log_d, about=node_mean)
    gap = mean - node_mean
    assert np.allclose(about, cov + np.outer(gap, gap), rtol=1e-12, atol=1e-15)
    assert np.linalg.eigvalsh(about - node_cov).min() > 0.0


def test_a_posterior_on_one_node_spreads_over_its_cells():
    """All mass on one interior node: the nodes' covariance is 0, the cells' is the hat
    function's, width² / 6 along each axis, centred on the node."""
    cells = Cells.base((-1.0, -2.0), (1.0, 2.0), (5, 5), 2)
    thetas = cells.thetas()
    log_d = np.full(len(thetas), -np.inf)
    at = int(np.argmin(np.sum((thetas - [0.5, 1.0]) ** 2, axis=1)))
    log_d[at] = 0.0
    mean, cov = cell_moments(cells, log_d)
    assert np.allclose(mean, [0.5, 1.0], atol=1e-15)
    assert np.allclose(cov, np.diag(np.array([0.5, 1.0]) ** 2 / 6.0), rtol=1e-12, atol=1e-15)


def test_the_density_anywhere_integrates_to_one_and_is_zero_outside_the_box():
    cells, log_d = _refined(MEAN, COV)
    axis = np.linspace(-3.0, 3.0, 241)
    grid = np.stack(np.meshgrid(axis, axis, indexing="ij"), axis=-1).reshape(-1, 2)
    step = axis[1] - axis[0]
    assert density_at(cells, log_d, grid).sum() * step**2 == pytest.approx(1.0, abs=1e-3)
    assert density_at(cells, log_d, np.array([[3.5, 0.0]]))[0] == 0.0
    with pytest.raises(ValueError, match="expected one a node"):
        density_at(cells, log_d[:-1], grid[:2])


def _conjugate_ranks(shrink: float, people: int = 300) -> dict[int, list[int]]:
    """SBC of a linear Gaussian model whose posterior is known: θ* ~ N(0, I), y = θ* + ε,
    ε ~ N(0, R); the posterior on refined cells (its covariance multiplied by ``shrink``:
    1 is Bayes, < 1 over-confident); each weight's rank among SAMPLES cell draws."""
    rng = np.random.default_rng(67)
    noise = np.array([[0.3, 0.05], [0.05, 0.2]])
    ranks: dict[int, list[int]] = {0: [], 1: []}
    for _ in range(people):
        theta = rng.multivariate_normal(np.zeros(2), np.eye(2))
        y = rng.multivariate_normal(theta, noise)
        cov = np.linalg.inv(np.eye(2) + np.linalg.inv(noise))
        mean = cov @ np.linalg.solve(noise, y)
        cells, log_d = _refined(mean, shrink * cov, lows=(-5.0, -5.0), highs=(5.0, 5.0))
        draws = cell_draws(cells, log_d, sbc.SAMPLES, rng)
        for i in range(2):
            ranks[i].append(int((draws[:, i] < theta[i]).sum()))
    return ranks


def test_the_rank_test_passes_bayes_and_fails_an_over_confident_posterior():
    """On a problem whose posterior is known, the ranks of cell draws are uniform (χ² p well
    above 0.01); a posterior a quarter as wide puts the truth at the extremes (a ∪ shape)."""
    exact = _conjugate_ranks(1.0)
    assert min(sbc.chi2_p(exact[i]) for i in range(2)) > 0.01
    narrow = _conjugate_ranks(0.25)
    assert max(sbc.chi2_p(narrow[i]) for i in range(2)) < 1e-6
    counts = sbc.rank_counts(narrow[0])
    assert counts[0] + counts[-1] > 3 * counts[4:6].sum() / 2


def _two_model_ranks(people: int, seed: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """Exact Bayes over a weight and which of two ways the person corrects: θ ~ N(0, 1), the
    step m is 1 or ½ with probability ½ each, five corrections y = mθ + N(0, 1). The
    posterior is a two-part Gaussian mixture, drawn from exactly. Returns each person's rank
    of θ* among :data:`~corrections_sim.study.sbc.SAMPLES` draws and their step."""
    rng = np.random.default_rng(seed)
    steps, n = np.array([1.0, 0.5]), 5
    ranks, which = [], []
    for _ in range(people):
        theta, m = rng.normal(), rng.integers(2)
        y = steps[m] * theta + rng.normal(size=n)
        var = 1.0 / (1.0 + n * steps**2)
        mean = var * steps * y.sum()
        # p(m | y): y ~ N(0, I + m² 11ᵀ); its log-density up to what both models share.
        log_w = -0.5 * (np.log1p(n * steps**2) - steps**2 * y.sum() ** 2 / (1 + n * steps**2))
        w = np.exp(log_w - log_w.max())
        parts = rng.choice(2, size=sbc.SAMPLES, p=w / w.sum())
        draws = rng.normal(mean[parts], np.sqrt(var[parts]))
        ranks.append(int((draws < theta).sum()))
        which.append(int(m))
    return np.array(ranks), np.array(which)


def test_a_group_of_one_correction_model_may_fail_where_exact_bayes_passes():
    """Why SBC's per-model p-values are diagnostics, not a test EX-M must pass: the ranks are
    uniform over the people drawn from the prior, not over the people of one latent way of
    correcting when the corrections cannot tell the ways apart. Exact Bayes over two steps
    passes the pooled test and fails within each step's people (∪ for the half steps, whose
    θ the mixture shrinks toward the full step's smaller |θ|, ∩ for the full steps)."""
    ranks, which = _two_model_ranks(4000)
    assert sbc.chi2_p(ranks) > 0.01
    half, full = ranks[which == 1], ranks[which == 0]
    assert sbc.chi2_p(half) < 1e-6 and sbc.chi2_p(full) < 1e-6
    ends = lambda r: sbc.rank_counts(r)[[0, -1]].sum() / len(r)  # noqa: E731
    assert ends(half) > 0.2 + 0.05 > ends(full) + 0.1  # uniform: 0.2


def test_the_people_come_from_the_robots_prior():
    """θ* inside the atlas's box, a model of EX-M's, a scale of its four, N positive
    definite; the same draw from the same seed."""
    settings = figure.load_settings(quick=True, overrides={})
    base = settings.base
    grid = base.atlas_spec().grid
    people = [sbc.draw_person(base, np.random.default_rng([67, d])) for d in range(40)]
    models = sbc.robot(base).models
    for person in people:
        assert np.all(person.theta >= grid.lows) and np.all(person.theta <= grid.highs)
        assert 0 <= person.model < len(models)
        assert person.scale in (1 / 16, 1 / 4, 1.0, 4.0)
        assert np.all(np.linalg.eigvalsh(person.noise) > 0)
    assert len({p.model for p in people}) > 3 and len({p.scale for p in people}) == 4
    again = sbc.draw_person(base, np.random.default_rng([67, 0]))
    assert np.array_equal(again.theta, people[0].theta)
    assert np.array_equal(again.noise, people[0].noise)


def test_the_person_corrects_exactly_as_each_of_the_robots_models_predicts():
    """Without noise, the features a drawn person shows are, to the bit, what the matching part
    of EX-M predicts at θ* (its plans read from the atlas there): the generative process SBC
    needs."""
    from corrections_sim.planning.features import feature_counts

    base = figure.load_settings(quick=True, overrides={}).base
    atlas, envs = base.atlas(), base.envs()
    robot = sbc.robot(base)
    rng = np.random.default_rng(5)
    for _ in range(3):
        env = envs[int(rng.integers(len(envs)))]
        theta_star, theta = rng.normal(size=2), rng.normal(size=2)
        intended = atlas.solve(theta_star, env).trajectory
        mine = atlas.solve(theta, env).trajectory
        for model, part in zip(robot.models, robot.parts(), strict=True):
            person = sbc.PriorPerson(correction=model, noise=np.zeros((2, 2)))
            shown = feature_counts(person.corrected_trajectory(mine, intended), env, base.features)
            h = part.observation().at_plans(atlas.plans(theta_star[None], env), mine, env,
                                            base.features)  # fmt: skip
            assert np.array_equal(shown, h[0])


def test_bad_settings_are_one_line(tmp_path, capsys):
    for option, message in [
        ("iterations=3", "iterations: SBC judges the posterior at t = 4, 12: needs at least 12"),
        ("atlas=false", "learners.EX-M: its grid is the study's plan atlas"),
        ("learners.EX-M.relevance=true", "learners.EX-M.relevance: SBC's people make every"),
    ]:
        argv = ["sbc", "--quick", "--set", option, "--out", str(tmp_path)]
        assert cli.main(argv) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"error: {message}") and err.count("\n") == 1
    argv = ["sbc", "--quick", "--set", "learners={ PP = { fixed_alpha = 0.2 } }", "--out"]
    argv.append(str(tmp_path))
    assert cli.main(argv) == 2
    assert "learners: PP has no posterior to draw from" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())


def test_the_command_writes_its_files_and_resumes(tmp_path):
    """Two people at CI's size: a row per person, learner and t; the summary's χ² p-value per
    learner, weight and t; run again, every person resumed and the same rows; on two workers,
    the same rows."""
    argv = ["sbc", "--quick", "--runs", "2", "--out", str(tmp_path), "--workers", "1"]
    assert cli.main(argv) == 0
    folder = tmp_path / "sbc"
    with open(folder / "draws.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 2 * 3 * len(sbc.AT)
    assert {r["learner"] for r in rows} == {"KF-C", "KF-CL", "EX-M"}
    assert all(0 <= int(r["rank_0"]) <= sbc.SAMPLES and 0 <= float(r["level"]) <= 1 for r in rows)
    assert all(r["p_model"] != "" for r in rows if r["learner"] == "EX-M")
    # Every learner met the same person.
    people = {(r["draw"], r["theta_star_0"], r["noise_01"], r["model"]) for r in rows}
    assert len(people) == 2
    summary = json.loads((folder / "summary.json").read_text())
    for learner in ("KF-C", "KF-CL", "EX-M"):
        for t in sbc.AT:
            entry = summary["sbc"][learner][str(t)]
            assert entry["draws"] == 2
            assert all(0.0 <= entry[f"weight_{i}"]["chi2_p"] <= 1.0 for i in range(2))
            assert sum(entry["weight_0"]["counts"]) == 2
    assert (folder / "sbc.png").stat().st_size > 10_000
    before = (folder / "draws.csv").read_bytes()
    assert cli.main([*argv, "--force"]) == 0
    assert json.loads((folder / "summary.json").read_text())["resumed_runs"] == 2
    assert (folder / "draws.csv").read_bytes() == before
    # Two workers, no cache: the same numbers.
    other = tmp_path / "two"
    two = ["sbc", "--quick", "--runs", "2", "--out", str(other), "--workers", "2"]
    assert cli.main(two) == 0
    assert (other / "sbc" / "draws.csv").read_bytes() == before
