"""EX-M's relevance (issue 66): the sum over which corrections were relevant, the person's
rate and noise scale integrated out, is the sum over every subset (checked against brute
force); the latest correction's probability of being relevant is that sum's; the irrelevant
density is a random nudge's, the same for every call; the move's direction is compared on the
waypoints the person moved; from the features alone a person whose corrections are all
relevant is believed more as they come, and with the direction a nudge is told from a
correction; bad values are one line."""

from __future__ import annotations

import csv
import itertools
import re

import numpy as np
import pytest
from scipy.special import betaln, gamma, iv, logsumexp

from corrections_sim.cli import main as cli
from corrections_sim.learning.base import make_learner
from corrections_sim.learning.exact.cells import Cells
from corrections_sim.learning.exact.relevance import (
    JudgedEntry,
    RelevantExact,
    log_vmf_ratio,
    nudge_density,
)
from corrections_sim.learning.exact.relevance import moved as moved_at
from corrections_sim.learning.exact.state import GridPosterior
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
    res = rng.normal(scale=0.7, size=(n, t, 3))  # residuals (2) and the moves' cosines
    res[:, :, 2] = rng.uniform(-1.0, 1.0, size=(n, t))
    grid = GridPosterior(thetas, log_d, None, t, cells, left=res)
    log_q = rng.normal(loc=-2.0, size=t)
    rows = np.zeros(2, bool)
    # Every other correction has a joint-space direction (7 a waypoint), the rest none.
    history = (
        PriorEntry(np.zeros(2), np.eye(2)),
        *(
            JudgedEntry(None, np.zeros((2, 7)), np.zeros(2), np.eye(2), q, rows, None)
            if i % 2
            else JudgedEntry(None, np.zeros((2, 7)), np.zeros(2), np.eye(2), q, rows, np.ones(7))
            for i, q in enumerate(log_q)
        ),
    )
    part = RelevantExact(
        noise_scales=(0.25, 1.0, 4.0),
        concentrations=(3.0, 50.0),
        relevance_prior=0.7,
        relevance_count=3.0,
    )
    prior = NoisePosterior.around(0.25 * np.eye(2), 4.0)
    return part, grid, prior, history, log_q


def _brute(part, grid, prior, history, log_q, forced_last=None) -> np.ndarray:
    """log p(z | θ) at every node by summing over every subset of relevant corrections
    (with the last one's relevance fixed when ``forced_last`` is given)."""
    a = part.relevance_prior * part.relevance_count
    b = part.relevance_count - a
    t = grid.count
    centre = prior.scale / (prior.dof - 3)
    combos = len(part.noise_scales) * len(part.concentrations)
    out = []
    for node in range(len(grid.thetas)):
        terms = []
        for s, kappa in itertools.product(part.noise_scales, part.concentrations):
            cov = s * centre
            for relevant in itertools.product([0, 1], repeat=t):
                if forced_last is not None and relevant[-1] != forced_last:
                    continue
                j = sum(relevant)
                total = betaln(a + j, b + t - j) - betaln(a, b) - np.log(combos)
                for i, on in enumerate(relevant):
                    if not on:
                        total += log_q[i]
                        continue
                    r = grid.left[node, i, :2]
                    total += -0.5 * r @ np.linalg.solve(cov, r) - 0.5 * np.log(
                        np.linalg.det(2 * np.pi * cov)
                    )
                    if history[1 + i].direction is not None:  # vMF(κ) over the uniform
                        total += _vmf_over_uniform(kappa, 7, grid.left[node, i, 2])
                terms.append(total)
        out.append(logsumexp(terms))
    return np.array(out)


def _vmf_over_uniform(kappa: float, dims: int, cos: float) -> float:
    """The von Mises–Fisher density on the sphere S^(dims − 1) over the uniform one, from
    its textbook normalizer (scipy's iv, not the exponentially scaled ive the code uses)."""
    nu = dims / 2 - 1
    normalizer = kappa**nu / ((2 * np.pi) ** (dims / 2) * iv(nu, kappa))
    area = 2 * np.pi ** (dims / 2) / gamma(dims / 2)
    return float(np.log(normalizer * area) + kappa * cos)


@pytest.mark.parametrize("t", [1, 4, 6])
def test_the_sum_over_relevant_subsets_is_brute_force(t):
    part, grid, prior, history, log_q = _case(t, t)
    mine = part._posterior(grid, prior, history) - grid.log_density
    np.testing.assert_allclose(mine, _brute(part, grid, prior, history, log_q), rtol=0, atol=1e-10)


def test_the_latest_correction_is_relevant_with_the_brute_force_probability():
    part, grid, prior, history, log_q = _case(11, 5)
    node = grid.log_density + np.log(grid.cells.coefficients)
    on = logsumexp(node + _brute(part, grid, prior, history, log_q, forced_last=1))
    off = logsumexp(node + _brute(part, grid, prior, history, log_q, forced_last=0))
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
    rows, move = moved_at(robot, moved)
    assert rows.sum() == 1 and rows[5] and np.array_equal(move, moved[5] - robot[5])
    size = float(np.linalg.norm(move))
    mean, cov = nudge_density(robot, rows, size, env, ("laptop", "table"), floor)
    again = nudge_density(robot, rows, size, env, ("laptop", "table"), floor)
    assert np.array_equal(mean, again[0]) and np.array_equal(cov, again[1])
    assert mean.shape == (2,) and np.all(np.linalg.eigvalsh(cov - floor) >= -1e-12)
    wider = nudge_density(robot, rows, 3.0 * size, env, ("laptop", "table"), floor)[1]
    assert np.trace(wider) > np.trace(cov)
    assert moved_at(robot, robot) == (None, None)


def test_a_concentration_of_zero_reads_no_direction():
    cos = np.array([-1.0, 0.0, 0.3, 1.0])
    out = log_vmf_ratio(np.array([0.0, 5.0]), 7, cos)
    assert np.array_equal(out[:, 0], np.zeros(4)) and np.all(np.diff(out[:, 1]) > 0)


def test_the_move_s_direction_is_compared_on_the_waypoints_the_person_moved():
    """A person who moves waypoint 5 onto ξ*'s: the waypoint model predicts that direction
    exactly (cos 1) at that ξ*, its opposite at the mirrored one, a right angle elsewhere;
    a model that moves every waypoint is compared on the same ones; a NaN plan stays NaN."""
    from corrections_sim.learning.exact.relevance import predicted_cosines
    from corrections_sim.people.corrections import DeformCorrection, WaypointCorrection

    rng = np.random.default_rng(1)
    robot = rng.uniform(-1.0, 1.0, size=(12, 7))
    intended = robot.copy()
    intended[5] += 0.2 * rng.normal(size=7)
    corrected = WaypointCorrection().apply(robot, intended)
    rows, move = moved_at(robot, corrected)
    direction = move / np.linalg.norm(move)
    mirrored = robot.copy()
    mirrored[5] -= intended[5] - robot[5]
    aside = robot.copy()
    aside[5] += np.linalg.svd((intended[5] - robot[5])[None])[2][-1]  # orthogonal
    plans = np.stack([intended, mirrored, aside, np.full_like(robot, np.nan)])
    cos = predicted_cosines(WaypointCorrection(), robot, plans, rows, direction)
    np.testing.assert_allclose(cos[:3], [1.0, -1.0, 0.0], atol=1e-12)
    assert np.isnan(cos[3])
    deform = predicted_cosines(DeformCorrection(), robot, plans[:1], rows, direction)
    assert deform[0] == pytest.approx(1.0)  # at the worst waypoint it moves all the way


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"relevance": "yes"}, "relevance: must be true or false"),
        ({"relevance": True, "relevance_prior": 1.0}, "relevance_prior: must lie in (0, 1)"),
        ({"relevance": True, "relevance_count": 0}, "relevance_count: must be a finite number > 0"),
        ({"relevance": True, "concentrations": [1, 1]}, "concentrations: lists a value twice"),
        ({"relevance": True, "noise": "fixed"}, 'noise: judging relevance needs noise = "learnt"'),
        ({"relevance_prior": 0.5}, "relevance_prior: only with relevance = true"),
        ({"concentrations": [4]}, "concentrations: only with relevance = true"),
        ({"relevance": True, "concentrations": [-1]}, "concentrations[0]: must be a number >= 0"),
    ],
)
def test_bad_relevance_values_are_one_line(params, message):
    with pytest.raises(ValueError, match="^learners.EX-M." + re.escape(message)):
        make_learner("EX-M", params)


STUDY = """\
theta_star = [1.0, -1.0]
runs = {runs}
iterations = {iterations}
seed = 4
environments = ["s0-t0-l1", "s1-t1-l2", "s2-t0-l0", "s0-t2-l2"]
atlas = {{ points = 9 }}
user = {user}
[learners.EX-M]
relevance = true
noise_scales = [0.0009765625, 0.00390625, 0.015625, 0.0625, 0.25, 1, 4]
{more}
"""


def _judged(tmp_path, **fields) -> list[dict]:
    path = tmp_path / "judged.toml"
    path.write_text(STUDY.format(**fields))
    assert cli.main(["study", str(path), "--out", str(tmp_path / "out"), "--workers", "1"]) == 0
    with open(tmp_path / "out" / "judged" / "curves.csv", newline="") as fh:
        return [r for r in csv.DictReader(fh) if r["relevance"] != ""]


def test_from_the_features_alone_a_relevant_person_is_believed_more_as_they_come(tmp_path):
    """The paper's person, relevance judged from the features alone (``concentrations =
    [0]``): the first correction is believed as the prior on the rate allows (0.94 measured);
    as the person's rate is learnt across their corrections each later one is believed more,
    past 0.99."""
    rows = _judged(tmp_path, runs=1, iterations=6, user='"biased"', more="concentrations = [0]")
    beta = [float(r["relevance"]) for r in rows]
    assert len(beta) == 6 and all(0.0 < b <= 1.0 for b in beta)
    assert beta[0] < 0.99 < beta[-1]


def test_the_move_s_direction_tells_a_nudge_from_a_correction(tmp_path):
    """The distracted person (30% of their corrections a nudge in a random joint-space
    direction, labelled), relevance judged from features and direction (the defaults):
    measured, 2 runs of 8 corrections, both nudges believed below 0.001 and every correction
    above 0.2 (from the features alone, a nudge of this study's first run was believed at
    0.999)."""
    user = '{ name = "distracted", fraction = 0.3 }'
    rows = _judged(tmp_path, runs=2, iterations=8, user=user, more="")
    nudges = [float(r["relevance"]) for r in rows if float(r["relevant"]) == 0.0]
    relevant = [float(r["relevance"]) for r in rows if float(r["relevant"]) == 1.0]
    assert nudges and relevant
    assert max(nudges) < 0.01 < 0.2 < min(relevant), (nudges, relevant)


def test_a_correction_that_moved_nothing_is_taken_in_but_not_judged(tmp_path):
    """A person whose plan is the robot's (θ* = θ̂⁰, both plans the atlas's) moves nothing:
    there is no move to call a nudge, so EX-M reports no β̂ for that correction (a study
    scores relevance over the corrections that moved something; the relevance study's nudges
    of no size were counted against EX-M, issue 66). The same person with the robot starting
    elsewhere is judged."""

    def first(theta0: str) -> dict:
        study = STUDY.replace("theta_star = [1.0, -1.0]", f"theta_star = [1.0, -1.0]\n{theta0}")
        path = tmp_path / "judged.toml"
        user = '{ name = "distracted", fraction = 0.5 }'
        path.write_text(study.format(runs=1, iterations=1, user=user, more=""))
        out = tmp_path / "out"
        assert cli.main(["study", str(path), "--out", str(out), "--workers", "1", "--force"]) == 0
        with open(out / "judged" / "curves.csv", newline="") as fh:
            rows = [r for r in csv.DictReader(fh) if r["learner"] == "EX-M"]
        return next(r for r in rows if r["iteration"] == "1")

    same = first("theta0 = [1.0, -1.0]")
    assert same.get("relevance", "") == ""  # not judged
    assert np.isfinite(float(same["theta_0"])) and np.isfinite(float(same["theta_1"]))
    assert 0.0 < float(first("theta0 = [0.0, 0.0]")["relevance"]) <= 1.0
