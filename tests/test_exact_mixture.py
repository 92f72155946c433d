"""EX-M, the exact posterior over θ, N and the person's correction model (issue 66): with one
model it is EX-CL to the bit; with several, the models' evidences decide between them, so a
person who corrects by a smooth deformation is found to, and learnt from as one; bad models
are refused in one line."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from scipy.special import logsumexp

from corrections_sim.cli import main as cli
from corrections_sim.learning.base import make_learner
from corrections_sim.learning.exact.mixture import MixtureState, model_tag

STUDY = """\
theta_star = [1.0, -1.0]
runs = 1
iterations = {iterations}
seed = 3
environments = ["s0-t0-l1", "s1-t1-l2"]
atlas = {{ points = 9 }}
user = {user}
[learners.EX-CL]
[learners.EX-M]
{models}
"""


def _study(folder, name, **fields) -> list[dict]:
    path = folder / f"{name}.toml"
    path.write_text(STUDY.format(**fields))
    argv = ["study", str(path), "--out", str(folder / "out"), "--workers", "1"]
    assert cli.main(argv) == 0
    with open(folder / "out" / name / "curves.csv", newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def one_model(tmp_path_factory):
    folder = tmp_path_factory.mktemp("one")
    models = 'models = ["waypoint"]\nnoise_scales = [1]'  # EX-CL's model and N's prior
    fields = {"iterations": 3, "user": '"biased"', "models": models}
    return _study(folder, "one", **fields)


@pytest.fixture(scope="module")
def deforming(tmp_path_factory):
    folder = tmp_path_factory.mktemp("deform")
    fields = {"iterations": 4, "user": '{ name = "deform", step = 1.0 }', "models": ""}
    return _study(folder, "deform", **fields)


def test_with_one_model_it_is_ex_cl_to_the_bit(one_model):
    ex_cl = [r for r in one_model if r["learner"] == "EX-CL"]
    ex_m = [r for r in one_model if r["learner"] == "EX-M"]
    assert len(ex_cl) == len(ex_m) == 4
    keys = ("theta_0", "theta_1", "cov_00", "cov_01", "cov_11", "nees", "regret", "nis")
    for a, b in zip(ex_cl, ex_m, strict=True):
        assert {k: a[k] for k in keys} == {k: b[k] for k in keys}
        assert float(b["model_waypoint"]) == 1.0
    assert float(ex_m[-1]["cov_00"]) < float(ex_m[0]["cov_00"])


def test_a_person_who_deforms_is_found_to_and_learnt_from(deforming):
    """The paper's person corrects one waypoint; this one deforms the path around it. EX-CL
    (one waypoint) is misled; EX-M's deformation model gains the most weight and its estimate
    ends nearer θ*."""
    ex_cl = [r for r in deforming if r["learner"] == "EX-CL"]
    ex_m = [r for r in deforming if r["learner"] == "EX-M"]
    probability = {k[len("model_") :]: float(v) for k, v in ex_m[-1].items() if k[:6] == "model_"}
    assert len(probability) == 6 and sum(probability.values()) == pytest.approx(1.0)
    assert [float(v) for k, v in ex_m[0].items() if k[:6] == "model_"] == pytest.approx([1 / 6] * 6)
    assert max(probability, key=probability.get) == "deform"
    assert probability["deform"] > 2 / 6
    assert float(ex_m[-1]["estimate_error"]) < 0.5 * float(ex_cl[-1]["estimate_error"])
    # The mixture's P holds the spread between the models' means: no smaller than its parts'
    # would allow, and positive definite.
    cov = np.array([[float(ex_m[-1]["cov_00"]), float(ex_m[-1]["cov_01"])]] * 2)
    cov[1] = [float(ex_m[-1]["cov_01"]), float(ex_m[-1]["cov_11"])]
    assert np.all(np.linalg.eigvalsh(cov) > 0)


def test_the_model_tags_name_what_differs_from_the_defaults():
    learner = make_learner("EX-M")
    assert [model_tag(m) for m in learner.models] == [
        "waypoint",
        "waypoint_step0.5",
        "waypoint_waypoints3",
        "deform",
        "deform_step0.5",
        "optimal",
    ]
    assert [p.model for p in learner.parts()] == list(learner.models)
    assert {p.noise for p in learner.parts()} == {"learnt"}
    assert make_learner("EX-M", {"noise": "fixed"}).parts()[0].noise == "fixed"


@pytest.mark.parametrize(
    ("models", "message"),
    [
        ("waypoint", "learners.EX-M.models = 'waypoint': expected a non-empty list"),
        ([], "learners.EX-M.models = []: expected a non-empty list"),
        (["waypoint", "waypoint"], "learners.EX-M.models: lists a model twice"),
        (["waypoint", {"name": "deform", "step": 2}], "learners.EX-M.models[1].step: must lie"),
        (["nudge"], "learners.EX-M.models[0]: unknown correction model 'nudge'"),
    ],
)
def test_bad_models_are_one_line(models, message):
    with pytest.raises(ValueError) as info:
        make_learner("EX-M", {"models": models})
    assert str(info.value).startswith(message), str(info.value)
    assert "\n" not in str(info.value)


def test_a_mixture_state_refuses_weights_that_do_not_sum_to_one():
    prior = make_learner("EX-M").initial
    from corrections_sim.belief import Belief, KalmanNoise

    belief = prior(Belief(theta=np.zeros(2), cov=np.eye(2)), KalmanNoise.isotropic(2, 0, 0.25))
    state = belief.state
    assert isinstance(state, MixtureState)
    assert logsumexp(state.log_weights) == pytest.approx(0.0)
    with pytest.raises(ValueError, match="not a normalized"):
        MixtureState(state.tags, state.parts, state.log_weights + 1.0)
    with pytest.raises(ValueError, match="one of each per model"):
        MixtureState(state.tags[:2], state.parts, state.log_weights)


def test_its_parameters_are_its_own_and_checked_where_ex_c_checks_them():
    from corrections_sim import components

    assert set(components.params(make_learner("EX-M"))) == {
        "models", "noise", "noise_dof", "noise_scales", "relevance", "concentrations",
        "relevance_prior", "relevance_count", "resolution", "cut", "max_level", "axes",
        "spread", "expand_traces", "expand_below", "expand_after", "expand_variances",
        "expand_noises", "expand_inputs", "expand_hidden",
    }  # fmt: skip
    with pytest.raises(ValueError, match=r"^learners.EX-M.resolution: must be a number >= 0"):
        make_learner("EX-M", {"resolution": -1})
    with pytest.raises(ValueError, match=r"^learners.EX-M.axes: must be"):
        make_learner("EX-M", {"axes": "some"})


def test_fig6_with_ex_m_pairs_it_with_every_other_learner(tmp_path):
    """A learners × users matrix with EX-M writes paired.csv: EX-M minus each other learner,
    per person, final error and regret, each the mean of the runs' differences."""
    import json

    argv = [
        "fig6", "--quick", "--out", str(tmp_path), "--learners", "EX-CL,EX-M", "--workers", "1",
        "--set", "atlas={ points = 9 }", "--set", 'environments=["s0-t0-l1", "s1-t1-l2"]',
    ]  # fmt: skip
    assert cli.main(argv) == 0
    folder = tmp_path / "fig6"
    summary = json.loads((folder / "summary.json").read_text())
    with open(folder / "curves.csv", newline="") as fh:
        curves = list(csv.DictReader(fh))
    users = list(summary["settings"])  # a matrix's settings: one entry a person
    assert len(summary["paired"]) == 2 * len(users) == 10
    for row in summary["paired"]:
        assert (row["a"], row["b"]) == ("EX-M", "EX-CL")
        metric = row["metric"].removeprefix("final ")
        last = {
            (r["learner"], r["run"]): float(r[metric])
            for r in curves
            if r["user"] == row["user"] and r["iteration"] == "2"
        }
        diff = [last[("EX-M", run)] - last[("EX-CL", run)] for run in ("0", "1")]
        assert row["mean"] == pytest.approx(np.mean(diff), rel=1e-12, abs=1e-12)
        assert row["n"] == 2
    assert (folder / "paired.csv").exists()
    # The matrix says which model EX-M ended on, for each person (the mean over runs).
    with open(folder / "matrix.csv", newline="") as fh:
        matrix = {(r["learner"], r["user"]): r for r in csv.DictReader(fh)}
    for user in users:
        mine = matrix[("EX-M", user)]
        final = [r for r in curves if r["user"] == user and r["learner"] == "EX-M"]
        final = [r for r in final if r["iteration"] == "2"]
        for key in [k for k in mine if k.startswith("model_")]:
            assert float(mine[key]) == pytest.approx(np.mean([float(r[key]) for r in final]))
        assert matrix[("EX-CL", user)]["model_waypoint"] == ""


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"noise_scales": []}, "learners.EX-M.noise_scales: expected a non-empty list"),
        ({"noise_scales": 0.5}, "learners.EX-M.noise_scales: expected a non-empty list"),
        ({"noise_scales": [1, 0]}, "learners.EX-M.noise_scales[1]: must be a number > 0"),
        ({"noise_scales": [1, True]}, "learners.EX-M.noise_scales[1]: must be a number > 0"),
        ({"noise_scales": [1, 1.0]}, "learners.EX-M.noise_scales: lists a value twice"),
        ({"noise": "fixed", "noise_scales": [1]}, "learners.EX-M.noise_scales: only with noise"),
    ],
)
def test_bad_noise_scales_are_one_line(params, message):
    with pytest.raises(ValueError) as info:
        make_learner("EX-M", params)
    assert str(info.value).startswith(message), str(info.value)
    assert "\n" not in str(info.value)


def test_the_parts_hold_the_noise_prior_asked_for():
    from corrections_sim.learning.exact.learners import ExactCorrectionAware
    from corrections_sim.learning.exact.mixture import DEFAULT_NOISE_SCALES, ScaledNoiseExact

    assert {p.noise_scales for p in make_learner("EX-M", {"noise_scales": [1]}).parts()} == {(1.0,)}
    assert {type(p) for p in make_learner("EX-M", {"noise": "fixed"}).parts()} == {
        ExactCorrectionAware
    }
    parts = make_learner("EX-M").parts()
    assert all(isinstance(p, ScaledNoiseExact) for p in parts)
    assert {p.noise_scales for p in parts} == {DEFAULT_NOISE_SCALES}


def test_the_scale_mixture_is_the_integral_over_n():
    """The scale mixture's marginal, p(r₁…rₜ | θ) = Σ_c π_c ∫ Πᵢ N(rᵢ; 0, N) IW(N; ν₀, c V₀)
    dN, against a Monte Carlo integral over N drawn from each IW: the ratio between two nodes
    (which the shared constants cancel from) and each scale's posterior weight."""
    from scipy import stats

    from corrections_sim.learning.exact.mixture import ScaledNoiseExact
    from corrections_sim.learning.exact.state import GridPosterior
    from corrections_sim.learning.kalman.state import NoisePosterior

    rng = np.random.default_rng(0)
    prior = NoisePosterior.around(0.25 * np.eye(2), 4.0)
    scales = (1 / 16, 1.0, 4.0)
    part = ScaledNoiseExact(model=make_learner("KF-C").model, noise="learnt", noise_scales=scales)
    residuals = [0.1 * rng.normal(size=(3, 2)), 0.8 * rng.normal(size=(3, 2))]  # two nodes
    scatter = np.array([r.T @ r for r in residuals])
    grid = GridPosterior(np.zeros((2, 2)), np.zeros(2), scatter, count=3)
    exact = part._noise_log_marginal(grid, prior)
    per_scale = part._log_marginals(grid, prior)

    def monte_carlo(r: np.ndarray, c: float) -> float:
        noise = stats.invwishart(df=prior.dof, scale=c * prior.scale).rvs(200_000, random_state=1)
        inv = np.linalg.inv(noise)
        _, logdet = np.linalg.slogdet(noise)
        quad = np.einsum("ti,nij,tj->n", r, inv, r)
        log_l = -0.5 * quad - 0.5 * len(r) * logdet - len(r) * np.log(2 * np.pi)
        return float(logsumexp(log_l) - np.log(len(log_l)))

    mc = np.array([[monte_carlo(r, c) for c in scales] for r in residuals])  # (node, c)
    mc_mix = logsumexp(mc, axis=1) - np.log(len(scales))
    assert exact[1] - exact[0] == pytest.approx(mc_mix[1] - mc_mix[0], abs=0.05)
    weights = np.exp(per_scale - logsumexp(per_scale, axis=1, keepdims=True))
    mc_weights = np.exp(mc - logsumexp(mc, axis=1, keepdims=True))
    np.testing.assert_allclose(weights, mc_weights, atol=0.02)
    assert weights[0, 0] > 0.99 and weights[1, 0] < 0.01  # small residuals: small N, not large


def test_a_grid_keeps_its_noise_marginals_and_a_grid_made_from_it_reuses_them(monkeypatch):
    """The log-determinants and noise marginals are kept with a grid: a grid made from it
    (made_from: some scatters changed, nodes appended) computes determinants only at the
    nodes whose scatter changed or that are new, and every value is the same bits as a grid
    computed afresh; a pickled grid leaves them behind."""
    import pickle

    from corrections_sim.learning.exact.mixture import DEFAULT_NOISE_SCALES, ScaledNoiseExact
    from corrections_sim.learning.exact.state import GridPosterior
    from corrections_sim.learning.kalman.state import NoisePosterior

    rng = np.random.default_rng(4)
    prior = NoisePosterior.around(0.25 * np.eye(2), 4.0)
    part = ScaledNoiseExact(
        model=make_learner("KF-C").model, noise="learnt", noise_scales=DEFAULT_NOISE_SCALES
    )
    r = rng.normal(size=(9, 2))
    scatter = np.einsum("ni,nj->nij", r, r)
    thetas = rng.normal(size=(9, 2))
    parent = GridPosterior(thetas, np.zeros(9), scatter, count=1)
    first = part._noise_log_marginal(parent, prior)
    assert part._noise_log_marginal(parent, prior) is first  # kept, not computed again

    changed = scatter.copy()
    changed[[2, 5]] += np.einsum("ni,nj->nij", r[:2], r[:2])
    grown = np.concatenate([changed, scatter[:3]])
    new_thetas = np.concatenate([thetas, rng.normal(size=(3, 2))])
    computed = []
    slogdet = np.linalg.slogdet
    monkeypatch.setattr(np.linalg, "slogdet", lambda a: computed.append(len(a)) or slogdet(a))
    child = GridPosterior(new_thetas, np.zeros(12), grown, count=2).made_from(parent)
    reused = part._noise_log_marginal(child, prior)
    assert computed == [5] * len(DEFAULT_NOISE_SCALES)  # nodes 2 and 5, and the 3 new ones
    afresh = GridPosterior(new_thetas, np.zeros(12), grown, count=2)
    np.testing.assert_array_equal(reused, part._noise_log_marginal(afresh, prior))
    np.testing.assert_array_equal(part._noise_means(child, prior), part._noise_means(afresh, prior))
    assert not reused.flags.writeable
    # A parent whose values are kept only after the child was made from it is read as well.
    late = GridPosterior(thetas, np.zeros(9), scatter, count=1)
    after = GridPosterior(new_thetas, np.zeros(12), grown, count=2).made_from(late)
    part._noise_log_marginal(late, prior)
    computed.clear()
    np.testing.assert_array_equal(part._noise_log_marginal(after, prior), reused)
    assert computed == [5] * len(DEFAULT_NOISE_SCALES)

    thawed = pickle.loads(pickle.dumps(child))
    assert "_memo" not in vars(thawed) and "_parent" not in vars(thawed)
    np.testing.assert_array_equal(part._noise_log_marginal(thawed, prior), reused)


def test_an_exact_learner_refuses_a_noise_prior_without_a_mean():
    from corrections_sim.belief import Belief, KalmanNoise
    from corrections_sim.components import ParameterError

    belief = Belief(theta=np.zeros(2), cov=np.eye(2))
    noise = KalmanNoise.isotropic(2, 0, 0.25)
    with pytest.raises(ParameterError, match=r"^noise_dof: must be > k \+ 1 = 3 for an exact"):
        make_learner("EX-CL", {"noise_dof": 2.5}).initial(belief, noise)
    make_learner("EX-CL", {"noise_dof": 3.5}).initial(belief, noise)
    make_learner("KF-CL", {"noise_dof": 2.5}).initial(belief, noise)  # KF-CL's N̂ is V / ν


def test_a_parameter_error_raised_in_a_worker_reaches_the_command():
    """Pickled and back, with its key and message (a bad value found inside a run once broke
    the process pool instead: "worker processes died 3 times")."""
    import pickle

    from corrections_sim.components import ParameterError

    back = pickle.loads(pickle.dumps(ParameterError("noise_dof", "must be > 3, got 2")))
    assert (type(back), back.name, back.message) == (
        ParameterError,
        "noise_dof",
        "must be > 3, got 2",
    )
    assert str(back) == "noise_dof: must be > 3, got 2"
