"""Bounded nonlinear least squares in numpy alone, for the optimiser's fit on a fish.

``scipy.optimize.least_squares`` solves the same problem, and the tests hold this one to it (the same
minimum on the optimiser's own fits and on textbook problems, ``test/control/test_lsq.py``).  But
``import scipy.optimize`` loads about 450 modules (sparse, spatial, HiGHS, ...) and 45 MB into every
process that imports it: two thirds of the controller's footprint, for a fit of 9 parameters.  A
fish's controller fits with this; identification, diagnosis and the campaign, which run on a desk,
keep scipy's.

The method is Levenberg-Marquardt in the scaled coordinates ``z = x / scale``, with the damping
updated by the gain ratio (Nielsen, 1999) and the bounds kept by projection: a parameter at a bound
whose gradient pushes it outwards is held there for the step (an active set, renewed every step).
The Jacobian is by forward differences of ``sqrt(eps) * max(1, |x|)``, stepped backwards at an upper
bound, as scipy's ``'2-point'``; its evaluations are not counted in ``max_nfev``, as scipy's are not.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import ControlError

FloatArray = NDArray[Any]

_REL_STEP = math.sqrt(float(np.finfo(float).eps))


@dataclass(frozen=True)
class Solution:
    """The minimiser ``x``, the residuals there (``fun``) and ``cost = 0.5 * fun @ fun``; ``nfev``
    evaluations of the residuals (the Jacobian's not counted) and why it stopped."""

    x: FloatArray
    fun: FloatArray
    cost: float
    nfev: int
    reason: str


def least_squares(
    fun: Callable[[FloatArray], FloatArray],
    x0: FloatArray,
    lower: FloatArray,
    upper: FloatArray,
    scale: FloatArray,
    max_nfev: int = 200,
    ftol: float = 1e-8,
    xtol: float = 1e-8,
    gtol: float = 1e-8,
) -> Solution:
    """Minimise ``0.5 * sum(fun(x) ** 2)`` over ``lower <= x <= upper`` from ``x0`` (clipped into the
    box); ``scale`` is each parameter's typical size (scipy's ``x_scale``).  The tolerances mean
    what scipy's do: a relative drop of the cost under ``ftol``, a step under ``xtol`` of the scaled
    vector, or a projected gradient under ``gtol``."""
    lower, upper, scale = (np.asarray(a, float) for a in (lower, upper, scale))
    if np.any(lower >= upper) or np.any(scale <= 0):
        raise ControlError("least_squares: each lower bound must lie below its upper, each scale above 0")
    x = np.clip(np.asarray(x0, float), lower, upper)
    r = np.asarray(fun(x), float)
    nfev, cost = 1, 0.5 * float(r @ r)
    damping, grow = -1.0, 2.0
    while True:
        steps = _REL_STEP * np.maximum(1.0, np.abs(x))  # (scipy's '2-point')
        jac = forward_differences(fun, x, steps, upper, r) * scale  # d r / d z
        grad = jac.T @ r
        held = ((x <= lower) & (grad > 0)) | ((x >= upper) & (grad < 0))
        free = ~held
        if not np.any(free) or float(np.max(np.abs(grad[free]))) < gtol:
            return Solution(x, r, cost, nfev, "gradient")
        jf, gf = jac[:, free], grad[free]
        normal = jf.T @ jf
        if damping < 0:  # Marquardt's start: a thousandth of the curvature's largest diagonal
            damping = 1e-3 * max(float(np.max(np.diag(normal))), 1e-300)
        while True:
            try:
                dz = np.linalg.solve(normal + damping * np.eye(len(gf)), -gf)
            except np.linalg.LinAlgError:
                dz = np.zeros(len(gf))
            trial = x.copy()
            trial[free] += scale[free] * dz
            trial = np.clip(trial, lower, upper)
            step = (trial - x) / scale
            small_step = float(np.linalg.norm(step)) < xtol * (xtol + float(np.linalg.norm(x / scale)))
            jstep = jac @ step
            predicted = -(float(grad @ step) + 0.5 * float(jstep @ jstep))
            r_new = np.asarray(fun(trial), float)
            nfev += 1
            cost_new = 0.5 * float(r_new @ r_new)
            drop = cost - cost_new
            if drop > 0 and np.isfinite(cost_new):
                rho = drop / predicted if predicted > 0 else 0.0
                damping *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
                grow = 2.0
                x, r, cost = trial, r_new, cost_new
                if drop < ftol * (cost + drop):
                    return Solution(x, r, cost, nfev, "cost")
                if small_step:
                    return Solution(x, r, cost, nfev, "step")
                if nfev >= max_nfev:
                    return Solution(x, r, cost, nfev, "max_nfev")
                break
            damping *= grow
            grow *= 2.0
            if nfev >= max_nfev or not np.isfinite(damping) or damping > 1e300:
                return Solution(x, r, cost, nfev, "max_nfev" if nfev >= max_nfev else "damping")
            if small_step:
                return Solution(x, r, cost, nfev, "step")


def forward_differences(
    fn: Callable[[FloatArray], FloatArray],
    x: FloatArray,
    steps: FloatArray,
    upper: FloatArray,
    at_x: FloatArray | None = None,
    skip: tuple[bool, ...] = (),
) -> FloatArray:
    """Forward differences of ``fn`` at ``x`` in each parameter (backwards where the step would cross
    ``upper``), shaped ``(*fn(x).shape, len(x))``; ``at_x`` is ``fn(x)`` when the caller has it, and
    a parameter flagged in ``skip`` gets zeros."""
    base = np.asarray(fn(x) if at_x is None else at_x, float)
    jac = np.zeros((*base.shape, len(x)))
    for k in range(len(x)):
        if k < len(skip) and skip[k]:
            continue
        xk = x.copy()
        xk[k] += steps[k] if xk[k] + steps[k] <= upper[k] else -steps[k]
        jac[..., k] = (np.asarray(fn(xk), float) - base) / (xk[k] - x[k])
    return jac
