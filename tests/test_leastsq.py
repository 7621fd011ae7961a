"""The least-squares core (identify/core/leastsq.py) against independent computations: the exact
linear least-squares solution, scipy's optimum on a nonlinear problem, bounds, held and unseen
directions, and the stopping rule that applies its last step without evaluating."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.optimize

from calbench.identify.core import covariance, levenberg_marquardt, svd_step


def linear_problem(seed=0, n=40, p=4):
    rng = np.random.default_rng(seed)
    a = rng.standard_normal((n, p)) * np.array([1.0, 10.0, 0.1, 3.0])
    x_true = rng.standard_normal(p)
    y = a @ x_true + rng.standard_normal(n)
    return a, y


def test_linear_problem_gives_the_normal_equations_solution_and_covariance():
    a, y = linear_problem()
    calls = []

    def ev(x):
        calls.append(1)
        return a @ x, a

    sol = levenberg_marquardt(ev, y, np.zeros(4), np.ones(4), step_tol=1e-9)
    exact = np.linalg.solve(a.T @ a, a.T @ y)
    # a linear model converges in one Gauss-Newton step: round-off only
    np.testing.assert_allclose(sol.x, exact, rtol=1e-10, atol=1e-12)
    assert sol.converged
    cov, rank = covariance(sol.j_w, np.ones(4, bool), np.ones(4), 1e-8)
    np.testing.assert_allclose(cov, np.linalg.inv(a.T @ a), rtol=1e-9)
    assert rank == 4


def test_sigma_rule_applies_the_last_step_without_evaluating_again():
    """With the start's evaluation in hand (the Monte Carlo case), a linear problem costs ONE
    evaluation: the trial of the first step; the second step is round-off, below step_tol
    sigma, and is applied without evaluating (final_eval=False)."""
    a, y = linear_problem(1)
    n = []

    def ev(x):
        n.append(1)
        return a @ x, a

    x0 = np.zeros(4)
    sol = levenberg_marquardt(ev, y, x0, np.ones(4), step_tol=1e-2, final_eval=False, start_eval=ev(x0))
    assert len(n) == 2  # the start_eval call made above, and one trial
    assert not sol.last_step_evaluated
    np.testing.assert_allclose(sol.x, np.linalg.lstsq(a, y, rcond=None)[0], rtol=1e-10)


def test_nonlinear_problem_reaches_scipys_optimum():
    t = np.linspace(0, 3, 30)
    rng = np.random.default_rng(2)
    y = 2.0 * np.exp(-1.3 * t) + 0.5 + 0.01 * rng.standard_normal(t.size)

    def model(x):
        e = np.exp(-x[1] * t)
        return x[0] * e + x[2], np.column_stack([e, -x[0] * t * e, np.ones_like(t)])

    x0 = np.array([1.0, 0.5, 0.0])
    sol = levenberg_marquardt(model, y, x0, np.ones(3), step_tol=1e-8, max_iter=100)
    ref = scipy.optimize.least_squares(
        lambda x: model(x)[0] - y, x0, jac=lambda x: model(x)[1], xtol=1e-14, ftol=1e-14, gtol=1e-14
    ).x
    cov, _ = covariance(sol.j_w, np.ones(3, bool), np.ones(3), 1e-10)
    # both at the optimum: agreement far inside the estimate's own standard deviation
    assert np.all(np.abs(sol.x - ref) < 1e-6 * np.sqrt(np.diag(cov)))
    assert sol.converged


def test_bounds_are_respected_and_the_bound_parameter_is_reported():
    a, y = linear_problem(3)
    exact = np.linalg.solve(a.T @ a, a.T @ y)
    lower = np.full(4, -np.inf)
    lower[1] = exact[1] + 0.5  # the unconstrained optimum violates it
    sol = levenberg_marquardt(
        lambda x: (a @ x, a),
        y,
        np.maximum(np.zeros(4), lower),
        np.ones(4),
        lower=lower,
        gain_tol=1e-12,
        cost_tol=1e-12,
        max_iter=100,
    )
    assert sol.x[1] == pytest.approx(lower[1])
    # the others are the constrained optimum: the linear LS with x1 fixed at its bound
    keep = [0, 2, 3]
    rest = np.linalg.lstsq(a[:, keep], y - a[:, 1] * lower[1], rcond=None)[0]
    np.testing.assert_allclose(sol.x[keep], rest, rtol=1e-6, atol=1e-9)


def test_held_and_unseen_directions_do_not_move():
    rng = np.random.default_rng(4)
    a = rng.standard_normal((30, 3))
    a = np.column_stack([a, a[:, 0] + a[:, 1]])  # column 3 = column 0 + column 1: one unseen direction
    y = a @ np.array([1.0, -2.0, 0.5, 0.0]) + 0.01 * rng.standard_normal(30)
    x0 = np.array([0.0, 0.0, 0.0, 0.3])
    hold = np.array([False, False, True, False])
    sol = levenberg_marquardt(lambda x: (a @ x, a), y, x0, np.ones(4), hold=hold, step_tol=1e-9)
    assert sol.x[2] == x0[2]  # held
    # minimum-norm steps in column-normalised coordinates (D = column norms): nothing moves
    # along the null vector (1, 1, 0, -1) there, i.e. (D dx) . (D null) = 0
    null = np.array([1.0, 1.0, 0.0, -1.0])
    d2 = np.linalg.norm(a, axis=0) ** 2
    assert abs((sol.x - x0) @ (d2 * null)) < 1e-10 * np.linalg.norm(sol.x - x0) * np.linalg.norm(d2 * null)
    # and the fit is the least-squares optimum with x2 held (unique in prediction space)
    free = [0, 1, 3]
    best = a[:, free] @ np.linalg.lstsq(a[:, free], y - a[:, 2] * x0[2], rcond=None)[0] + a[:, 2] * x0[2]
    np.testing.assert_allclose(a @ sol.x, best, rtol=1e-8, atol=1e-10)


def test_svd_step_standard_deviations_match_the_inverse_normal_matrix():
    a, y = linear_problem(5)
    du, sd, rank = svd_step(a, y, 0.0, 1e-12)
    assert rank == 4
    np.testing.assert_allclose(sd, np.sqrt(np.diag(np.linalg.inv(a.T @ a))), rtol=1e-10)


def test_failed_evaluations_are_damped_not_fatal():
    a, y = linear_problem(6)
    exact = np.linalg.lstsq(a, y, rcond=None)[0]

    def ev(x):
        if np.linalg.norm(x - exact) > 0.9 * np.linalg.norm(exact):  # far trials have no solution
            raise RuntimeError("no equilibrium")
        return a @ x, a

    x0 = 0.5 * exact
    sol = levenberg_marquardt(ev, y, x0, np.ones(4), step_tol=1e-9, final_eval=True, max_iter=50)
    np.testing.assert_allclose(sol.x, exact, rtol=1e-8)


def test_active_set_frees_a_correlated_parameter_the_bound_does_not_hold():
    """Two correlated parameters both start on their lower bounds; the constrained optimum has
    only one of them there. Fixing both because both undamped steps point outward (the old rule)
    stops at the corner; fixing the worst one first finds the optimum (scipy's bounded linear
    least squares as the independent reference)."""
    rng = np.random.default_rng(7)
    t = rng.standard_normal((50, 1))
    # anti-correlated columns, unconstrained optimum (-3, -0.5): both undamped steps from the
    # corner point outward, yet with x0 held at 0 the best x1 is positive
    a = np.column_stack([t[:, 0], -0.9 * t[:, 0] + 0.1 * rng.standard_normal(50)])
    y = a @ np.array([-3.0, -0.5]) + 0.01 * rng.standard_normal(50)
    lower = np.zeros(2)
    ref = scipy.optimize.lsq_linear(a, y, bounds=(lower, np.inf)).x
    assert ref[0] < 1e-9 and ref[1] > 0.1  # the case: one bound active
    sol = levenberg_marquardt(
        lambda x: (a @ x, a), y, lower.copy(), np.ones(2), lower=lower, step_tol=1e-9, max_iter=50
    )
    assert sol.converged
    np.testing.assert_allclose(sol.x, ref, atol=1e-9)


def test_a_small_step_a_bound_clips_is_evaluated_not_applied_blind():
    """The sigma rule applies a step below step_tol std without evaluating. Along a split the data
    barely see (x1 - x2: std ~10) a step can be tiny in each parameter's own std yet cross a
    bound; applied clipped, it moved the determined sum x1 + x2 (std ~7e-4) by the clipped part:
    0.01, ~14 of its std (discovery's self-check met it on the FANUC's k3 + forearm pitch). It
    must end at the constrained optimum instead: x2 on its bound, x1 the exact 1-D solution."""
    a = 1e3 * np.array([[1.0, 1.0], [1.0, 1.0 + 1e-4], [1.0, 1.0 - 1e-4]])
    x0 = np.array([1.0, 1e-3])
    y = a @ (x0 + np.array([0.01, -0.01]))  # exact optimum: x2 = 1e-3 - 0.01 < 0
    lower = np.array([0.0, 0.0])
    sol = levenberg_marquardt(
        lambda x: (a @ x, a), y, x0, np.ones(2), lower=lower, step_tol=1e-2, final_eval=False
    )
    x1 = float(a[:, 0] @ y / (a[:, 0] @ a[:, 0]))  # x2 held on its bound
    sd_sum = float(np.sqrt(np.array([1.0, 1.0]) @ np.linalg.inv(a.T @ a) @ np.array([1.0, 1.0])))
    assert sol.x[1] == 0.0
    assert abs(sol.x.sum() - x1) < 0.1 * sd_sum
    assert sol.converged
