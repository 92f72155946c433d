"""The learnt feature's optimizer (``planning/lbfgs.py``): it minimises, says why it stopped,
and its path does not depend on the order a sum is taken in — the property that makes it give
the same bits under any BLAS kernel (a learnt feature's loss is not convex, so a last-bit
difference grows into another local minimum)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize as scipy_minimize

from corrections_sim.learnt import lbfgs


def _quadratic(n: int, rng: np.random.Generator):
    """½ xᵀAx − bᵀx with A's condition number 1e3, and its minimiser A⁻¹b."""
    q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    a = q @ np.diag(np.logspace(0, 3, n)) @ q.T
    b = rng.normal(size=n)

    def f(x):
        ax = a @ x
        return 0.5 * float(x @ ax) - float(b @ x), ax - b

    return f, np.linalg.solve(a, b)


def _rosenbrock(x):
    value = np.sum(100.0 * (x[1:] - x[:-1] ** 2) ** 2 + (1.0 - x[:-1]) ** 2)
    grad = np.zeros_like(x)
    grad[:-1] = -400.0 * x[:-1] * (x[1:] - x[:-1] ** 2) - 2.0 * (1.0 - x[:-1])
    grad[1:] += 200.0 * (x[1:] - x[:-1] ** 2)
    return float(value), grad


def test_it_finds_the_minimum_of_an_ill_conditioned_quadratic(rng):
    f, best = _quadratic(30, rng)
    result = lbfgs.minimize(f, np.zeros(30), max_iter=2000, gtol=1e-6, ftol=0.0)
    assert result.reason == "gradient" and result.converged
    np.testing.assert_allclose(result.x, best, atol=1e-5)  # ‖x − x*‖ ≤ ‖∇f‖ / λ_min
    assert np.max(np.abs(result.grad)) <= 1e-6


@pytest.mark.parametrize("n", [2, 10])
def test_it_walks_the_rosenbrock_valley_to_its_end(n):
    result = lbfgs.minimize(_rosenbrock, np.full(n, -1.2), max_iter=5000, gtol=1e-8, ftol=0.0)
    assert result.converged
    np.testing.assert_allclose(result.x, np.ones(n), atol=1e-6)
    assert result.fun < 1e-12 and result.evaluations >= result.iterations


def test_it_ends_where_scipys_l_bfgs_ends_on_a_smooth_convex_problem(rng):
    f, _ = _quadratic(12, rng)
    ours = lbfgs.minimize(f, np.ones(12), max_iter=1000, gtol=1e-6, ftol=0.0)
    theirs = scipy_minimize(f, np.ones(12), jac=True, method="L-BFGS-B",
                            options={"maxiter": 1000, "gtol": 1e-6, "ftol": 0.0})  # fmt: skip
    assert ours.converged and theirs.success
    assert ours.fun == pytest.approx(theirs.fun, rel=1e-10)
    np.testing.assert_allclose(ours.x, theirs.x, atol=1e-5)


def test_a_stop_at_the_iteration_limit_says_so():
    result = lbfgs.minimize(_rosenbrock, np.full(4, -1.2), max_iter=5)
    assert result.reason == "iterations" and not result.converged and result.iterations == 5
    assert result.fun < _rosenbrock(np.full(4, -1.2))[0]  # every accepted step descends


def test_the_inner_product_is_the_same_bits_in_any_order(rng):
    a, b = rng.normal(size=997) * 1e3, rng.normal(size=997)
    order = rng.permutation(997)
    assert lbfgs.dot(a, b) == lbfgs.dot(a[order], b[order])
    assert lbfgs.dot(a, b) == pytest.approx(float(np.dot(a, b)), rel=1e-12)


def test_permuting_the_coordinates_permutes_the_path_bit_for_bit(rng):
    """Every sum it takes is order-free, so the problem with its coordinates shuffled is solved
    along the shuffled path: the same bits, stopped at the same step. (A BLAS kernel changes
    only the order of a sum, so it changes nothing either.) Stopped part-way on a non-convex
    loss, where a last-bit difference would show."""
    n = 40
    w = rng.normal(size=(n, n)) / np.sqrt(n)
    target = rng.normal(size=n)

    def f(x):  # a small tanh regression: non-convex, like a learnt feature's loss
        h = np.tanh(w @ x)
        r = h - target
        return 0.5 * lbfgs.dot(r, r) + 1e-3 * lbfgs.dot(x, x), w.T @ (r * (1 - h**2)) + 2e-3 * x

    order = rng.permutation(n)
    back = np.argsort(order)

    def f_shuffled(y):  # y = x[order]; f in the shuffled coordinates
        value, grad = f(y[back])
        return value, grad[order]

    x0 = rng.normal(size=n)
    plain = lbfgs.minimize(f, x0, max_iter=60)
    shuffled = lbfgs.minimize(f_shuffled, x0[order], max_iter=60)
    assert plain.iterations == shuffled.iterations and plain.reason == shuffled.reason
    assert plain.fun == shuffled.fun
    assert np.array_equal(plain.x[order], shuffled.x)


@pytest.mark.parametrize(
    "kwargs", [{"max_iter": 0}, {"memory": 0}, {"max_line": 0}, {"gtol": 0.0}, {"ftol": -1.0}]
)
def test_bad_settings_are_refused(kwargs):
    with pytest.raises(ValueError, match="max_iter"):
        lbfgs.minimize(_rosenbrock, np.zeros(2), **kwargs)
