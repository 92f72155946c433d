"""EX-M's relevance (issue 66): the sum over which corrections were relevant, the person's
rate and noise scale integrated out, is the sum over every subset (checked against brute
force); the latest correction's probability of being relevant is that sum's; the irrelevant
density is a random nudge's, the same for every call; a person whose corrections are all
relevant is believed more as they come; bad values are one line."""

from __future__ import annotations

import csv
import itertools

import numpy as np
import pytest
from scipy.special import betaln, logsumexp

from corrections_sim.cli import main as cli
from corrections_sim.learning.base import make_learner
from corrections_sim.learning.exact.cells import Cells
from corrections_sim.learning.exact.relevance import (
    JudgedEntry,
    RelevantExact,
    _ResidualGrid,
    nudge_density,
)
from corrections_sim.learning.history import PriorEntry
from corrections_sim.learning.kalman.state import NoisePosterior
from corrections_sim.scene.environments import paper_environments


def _case(seed: int, t: int):
    """A small grid with random residuals and irrelevant densities, and the part."""
    rng = np.random.default_rng(seed)
    cells = Cells.base(np.array([-1.0, -1.0]), np.array([1.0, 1.0]), np.array([3, 3]), 2)
    thetas = cells.thetas()
    n = len(thetas)
    log_d = rng.normal(size=n)
    res = rng.normal(scale=0.7, size=(n, t, 2))
    grid = _ResidualGrid(thetas, log_d, res, t, cells)
    log_q = rng.normal(loc=-2.0, size=t)
    history = (
        PriorEntry(np.zeros(2), np.eye(2)),
        *(JudgedEntry(None, np.zeros((2, 7)), np.zeros(2), np.eye(2), q) for q in log_q),
    )
    part = RelevantExact(noise_scales=(0.25, 1.0, 4.0), relevance_prior=0.7, relevance_count=3.0)
    prior = NoisePosterior.around(0.25 * np.eye(2), 4.0)
    return part, grid, prior, history, log_q


def _brute(part, grid, prior, log_q, forced_last=None) -> np.ndarray:
    """log p(z | θ) at every node by summing over every subset of relevant corrections
    (with the last one's relevance fixed when ``forced_last`` is given)."""
    a = part.relevance_prior * part.relevance_count
    b = part.relevance_count - a
    t = grid.count
    centre = prior.scale / (prior.dof - 3)
    out = []
    for node in range(len(grid.thetas)):
        terms = []
        for s in part.noise_scales:
            cov = s * centre
            for relevant in itertools.product([0, 1], repeat=t):
                if forced_last is not None and relevant[-1] != forced_last:
                    continue
                j = sum(relevant)
                total = betaln(a + j, b + t - j) - betaln(a, b) - np.log(len(part.noise_scales))
                for i, on in enumerate(relevant):
                    if on:
                        r = grid.scatter[node, i]
                        total += -0.5 * r @ np.linalg.solve(cov, r) - 0.5 * np.log(
                            np.linalg.det(2 * np.pi * cov)
                        )
                    else:
                        total += log_q[i]
                terms.append(total)
        out.append(logsumexp(terms))
    return np.array(out)


@pytest.mark.parametrize("t", [1, 4, 6])
def test_the_sum_over_relevant_subsets_is_brute_force(t):
    part, grid, prior, history, log_q = _case(t, t)
    mine = part._posterior(grid, prior, history) - grid.log_density
    np.testing.assert_allclose(mine, _brute(part, grid, prior, log_q), rtol=0, atol=1e-10)


def test_the_latest_correction_is_relevant_with_the_brute_force_probability():
    part, grid, prior, history, log_q = _case(11, 5)
    node = grid.log_density + np.log(grid.cells.coefficients)
    on = logsumexp(node + _brute(part, grid, prior, log_q, forced_last=1))
    off = logsumexp(node + _brute(part, grid, prior, log_q, forced_last=0))
    assert part._relevance(grid, prior, history) == pytest.approx(
        np.exp(on - np.logaddexp(on, off))
    )


def test_a_correction_certain_to_be_relevant_is_so():
    part, grid, prior, history, _ = _case(5, 3)
    last = history[-1]
    sure = (*history[:-1], JudgedEntry(last.env, last.robot, last.phi_h, last.noise))
    assert part._relevance(grid, prior, sure) == 1.0


def test_the_irrelevant_density_is_a_random_nudge_of_the_same_size():
    env = paper_environments()[0]
    rng = np.random.default_rng(0)
    robot = rng.uniform(-1.0, 1.0, size=(12, 7))
    moved = robot.copy()
    moved[5] += 0.3 * rng.normal(size=7)
    floor = 1e-3 * np.eye(2)
    mean, cov = nudge_density(robot, moved, env, ("laptop", "table"), floor)
    again = nudge_density(robot, moved, env, ("laptop", "table"), floor)
    assert np.array_equal(mean, again[0]) and np.array_equal(cov, again[1])
    assert mean.shape == (2,) and np.all(np.linalg.eigvalsh(cov - floor) >= -1e-12)
    bigger = robot.copy()
    bigger[5] += 3.0 * (moved[5] - robot[5])
    assert np.trace(nudge_density(robot, bigger, env, ("laptop", "table"), floor)[1]) > np.trace(
        cov
    )
    assert nudge_density(robot, robot, env, ("laptop", "table"), floor) is None


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"relevance": "yes"}, "relevance: must be true or false"),
        (
            {"relevance": True, "relevance_prior": 1.0},
            "relevance_prior: must be a number in (0, 1)",
        ),
        ({"relevance": True, "relevance_count": 0}, "relevance_count: must be a number > 0"),
        ({"relevance": True, "noise": "fixed"}, 'noise: judging relevance needs noise = "learnt"'),
        ({"relevance_prior": 0.5}, "relevance_prior: only with relevance = true"),
    ],
)
def test_bad_relevance_values_are_one_line(params, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        make_learner("EX-M", params)


STUDY = """\
theta_star = [1.0, -1.0]
runs = 1
iterations = 6
seed = 4
environments = ["s0-t0-l1", "s1-t1-l2", "s2-t0-l0", "s0-t2-l2"]
atlas = { points = 9 }
user = "biased"
[learners.EX-M]
relevance = true
noise_scales = [0.0009765625, 0.015625, 0.25, 4]
"""


def test_a_person_whose_corrections_are_all_relevant_is_believed_more_as_they_come(tmp_path):
    """The paper's person: every correction is relevant. The first is believed as the prior
    on the rate allows (0.9 on average); as the person's rate is learnt across their
    corrections each later one is believed more, past 0.99 (measured: 0.94 at the first)."""
    path = tmp_path / "relevant.toml"
    path.write_text(STUDY)
    assert cli.main(["study", str(path), "--out", str(tmp_path / "out"), "--workers", "1"]) == 0
    with open(tmp_path / "out" / "relevant" / "curves.csv", newline="") as fh:
        beta = [float(r["relevance"]) for r in csv.DictReader(fh) if r["relevance"] != ""]
    assert len(beta) == 6 and all(0.0 < b <= 1.0 for b in beta)
    assert beta[-1] > 0.99 and beta[-1] > beta[0]
