"""The fish's bounded least squares (``control/lsq.py``) reaches the minimum scipy's does: on the
optimiser's own fits, on bounded linear problems with a known unique answer, and on a nonlinear
textbook fit; and it keeps its box and its budget."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import optimize

from piezofin_ros.bench import evaluation
from piezofin_ros.bench.plants import Plant
from piezofin_ros.control import fit as fitmod
from piezofin_ros.control.correction import PRIOR_SIGMA, vector_of
from piezofin_ros.control.lsq import Solution, least_squares
from piezofin_ros.control.optimise import OperatingBox, Optimiser
from piezofin_ros.errors import ControlError
from piezofin_ros.physics.effects import DragOffset, Leakage
from piezofin_ros.physics.fin import load_fin


def scipy_solve(fun: Any, x0: Any, lower: Any, upper: Any, scale: Any, max_nfev: int) -> Solution:
    r = optimize.least_squares(fun, x0, bounds=(lower, upper), x_scale=scale, max_nfev=max_nfev)
    return Solution(r.x, r.fun, float(r.cost), int(r.nfev), str(r.status))


@pytest.mark.fast_cases("a fish, more drag")  # (each case 4-6 s: the others in the whole suite)
@pytest.mark.parametrize(
    ("plant", "settings_"),
    [
        pytest.param(lambda fin: Plant(fin, loss_tan_delta=0.02), {}, id="vibrometer, a lossy fin"),
        pytest.param(
            lambda fin: Plant(fin, loss_tan_delta=0.03, effects=(Leakage(0.08),)),
            {"demand_n": 3e-3, "source": "self"},
            id="self-sensed, a leak",
        ),
        pytest.param(
            lambda fin: Plant(fin, effects=(DragOffset(1.5),)),
            {"demand_n": 3e-3, "source": "self", "watt": "supply"},
            id="a fish, more drag",
        ),
        pytest.param(lambda fin: Plant(fin), {"source": "loadcell", "demand_n": 2e-3}, id="load cell"),
    ],
)
def test_every_fit_of_the_optimiser_reaches_scipys_minimum(
    monkeypatch: pytest.MonkeyPatch, plant: Any, settings_: dict[str, Any]
) -> None:
    """Each fit the optimiser makes over 12 trials, made again with ``scipy.optimize.least_squares``
    (trust-region reflective) on the same residuals from the same start: the reduced chi-square
    within 1e-5 of scipy's (relative) and each parameter within 1e-3 of its prior's width (measured:
    3e-5 at worst over 30 trials of each)."""
    fin = load_fin("M8528-P1")
    original = fitmod.FitProblem.fit
    seen: list[tuple[int, float, float, float]] = []

    def both(self: fitmod.FitProblem, obs: Any, start: Any, solve: Any = least_squares) -> fitmod.Fit:
        ours, theirs = original(self, obs, start), original(self, obs, start, solve=scipy_solve)
        gap = np.max(np.abs(vector_of(ours.correction) - vector_of(theirs.correction)) / PRIOR_SIGMA)
        seen.append((len(obs), ours.chi2, theirs.chi2, float(gap)))
        return ours

    monkeypatch.setattr(fitmod.FitProblem, "fit", both)
    opt = Optimiser(fin, OperatingBox(1.0, 20.0, 50.0, 800.0), **settings_)
    rng, t = np.random.default_rng(5), 0.0
    for _ in range(12):
        t = evaluation.run_trial(opt, plant(fin), t, rng)
    assert len(seen) >= 10
    for n, ours, theirs, gap in seen:
        assert ours <= theirs * (1 + 1e-5) + 1e-9, (n, ours, theirs)
        assert gap < 1e-3, (n, gap)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    m=st.integers(3, 20),
    n=st.integers(1, 6),
    width=st.floats(0.05, 3.0),
)
def test_a_bounded_linear_problem_reaches_its_unique_minimum(seed: int, m: int, n: int, width: float) -> None:
    """``|A x - b|^2`` over a box, A of full column rank: one minimum, often with bounds active
    (the box is narrow against the unconstrained answer); scipy's ``lsq_linear`` gives it exactly."""
    n = min(n, m)  # (full column rank: no more unknowns than rows)
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(m, n)) + np.eye(m, n) * 3.0
    b = rng.normal(size=m) * 3.0
    lower = rng.uniform(-width, 0.0, size=n)
    upper = lower + rng.uniform(0.01, 2 * width, size=n)
    exact = optimize.lsq_linear(a, b, bounds=(lower, upper), tol=1e-14)
    scale = rng.uniform(0.1, 10.0, size=n)
    got = least_squares(lambda x: a @ x - b, (lower + upper) / 2, lower, upper, scale, max_nfev=500)
    assert np.all(got.x >= lower) and np.all(got.x <= upper)
    assert got.cost <= float(exact.cost) * (1 + 1e-6) + 1e-10, (got, exact.cost)
    assert np.allclose(got.x, exact.x, atol=1e-4 * (1 + np.abs(exact.x).max()))


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    amplitude=st.floats(0.5, 5.0),
    rate=st.floats(0.2, 3.0),
    cap=st.floats(0.1, 4.0),
)
def test_a_nonlinear_fit_with_a_bound_reaches_scipys_minimum(
    seed: int, amplitude: float, rate: float, cap: float
) -> None:
    """A decay ``a exp(-k t) + c`` fitted to noisy samples, the rate capped at ``cap`` (active when the
    true rate is above it): the same cost as scipy's, from the same start."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 4.0, 30)
    y = amplitude * np.exp(-rate * t) + 0.3 + rng.normal(0.0, 0.02, t.size)

    def fun(x: Any) -> Any:
        return x[0] * np.exp(-x[1] * t) + x[2] - y

    lower, upper, x0 = np.array([0.0, 0.01, -1.0]), np.array([10.0, cap, 1.0]), np.array([1.0, 0.05, 0.0])
    scale = np.ones(3)
    ours = least_squares(fun, x0, lower, upper, scale, max_nfev=400)
    theirs = scipy_solve(fun, x0, lower, upper, scale, 400)
    assert ours.cost <= theirs.cost * (1 + 1e-6) + 1e-10, (ours, theirs)


def test_the_box_and_the_budget_hold() -> None:
    """Every point it evaluates is inside the box (a start outside is clipped in); it stops at
    ``max_nfev``; a box that is empty or a scale not above 0 is refused by name."""
    lower, upper = np.array([-1.0, 0.5]), np.array([1.0, 2.0])
    asked: list[Any] = []

    def rosenbrock(x: Any) -> Any:
        asked.append(x.copy())
        return np.array([10 * (x[1] - x[0] ** 2), 1 - x[0]])

    got = least_squares(rosenbrock, np.array([-5.0, 9.0]), lower, upper, np.ones(2), max_nfev=7)
    assert got.reason == "max_nfev" and got.nfev == 7
    assert all(np.all(x >= lower - 1e-12) and np.all(x <= upper + 1e-12) for x in asked)
    done = least_squares(rosenbrock, np.array([-0.5, 1.5]), lower, upper, np.ones(2))
    assert np.allclose(done.x, [1.0, 1.0], atol=1e-6) and done.cost < 1e-12
    with pytest.raises(ControlError, match="lower bound"):
        least_squares(rosenbrock, np.zeros(2), upper, lower, np.ones(2))
    with pytest.raises(ControlError, match="scale"):
        least_squares(rosenbrock, np.zeros(2), lower, upper, np.zeros(2))
