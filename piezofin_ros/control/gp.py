"""A Gaussian process on the corrected model's residuals: what the model misses, learnt from the trials.

The optimiser's map is the fin model with a fitted correction (:mod:`.optimise`); whatever that
correction cannot express (an effect outside its family) shows up as residuals of the measured log
thrust and log power.  A Gaussian process with a squared-exponential kernel in ``(log f, V / 800)``
interpolates them: near the trials the map follows the measurements, far from them it reverts to
the model (the prior mean is zero: the model).  Its variance says how far the map can be trusted,
which sets the demand's margin and where the search may go.

Twenty lines of numpy rather than scikit-learn: the hyperparameters are fixed by the physics (a
resonance is a few per cent wide in frequency), the data are tens of points, and the controller runs
on a fish, where importing scikit-learn would double its memory.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[Any]


@dataclass
class ResidualGP:
    """Zero-mean GP regression of one or more residual columns on ``(log f, V / 800)``."""

    length_log_f: float = 0.08  # correlation length in log frequency (8 %)
    length_v: float = 0.25  # and in V / 800
    _x: FloatArray = field(default_factory=lambda: np.empty((0, 2)))
    _alpha: FloatArray = field(default_factory=lambda: np.empty((0, 0)))
    _chol: FloatArray = field(default_factory=lambda: np.empty((0, 0)))
    _signal: FloatArray = field(default_factory=lambda: np.empty(0))

    def _features(self, f: Any, v: Any) -> FloatArray:
        f, v = np.broadcast_arrays(np.asarray(f, float), np.asarray(v, float))
        return np.column_stack([np.log(f.ravel()) / self.length_log_f, v.ravel() / 800.0 / self.length_v])

    @staticmethod
    def _kernel(a: FloatArray, b: FloatArray) -> FloatArray:
        d2 = np.sum(a * a, 1)[:, None] + np.sum(b * b, 1)[None, :] - 2.0 * a @ b.T
        return np.asarray(np.exp(-0.5 * np.maximum(d2, 0.0)))

    def fit(self, f: FloatArray, v: FloatArray, residuals: FloatArray, noise: FloatArray) -> None:
        """``residuals`` (n, m) with their noise (n, m) standard deviations; the signal variance of
        each column is the residuals' mean square beyond the noise (zero residuals: no correction)."""
        r = np.asarray(residuals, float).reshape(len(f), -1)
        s = np.asarray(noise, float).reshape(r.shape)
        self._x = self._features(f, v)
        self._signal = np.maximum(np.mean(r * r - s * s, axis=0), 0.0)
        k = self._kernel(self._x, self._x)
        n, m = r.shape
        self._chol = np.empty((m, n, n))
        self._alpha = np.empty((n, m))
        for j in range(m):
            cov = self._signal[j] * k + np.diag(s[:, j] ** 2 + 1e-12)
            chol = np.linalg.cholesky(cov)
            self._chol[j] = chol
            self._alpha[:, j] = np.linalg.solve(chol.T, np.linalg.solve(chol, r[:, j]))

    @property
    def empty(self) -> bool:
        return self._x.shape[0] == 0

    def predict(self, f: Any, v: Any) -> tuple[FloatArray, FloatArray]:
        """Posterior mean and variance of each column at the points, shapes ``(points, m)``."""
        x = self._features(f, v)
        if self.empty:
            return np.zeros((len(x), 1)), np.zeros((len(x), 1))
        kx = self._kernel(x, self._x)  # (p, n)
        m = self._alpha.shape[1]
        mean = np.empty((len(x), m))
        var = np.empty((len(x), m))
        for j in range(m):
            mean[:, j] = self._signal[j] * kx @ self._alpha[:, j]
            w = np.linalg.solve(self._chol[j], (self._signal[j] * kx).T)
            var[:, j] = np.maximum(self._signal[j] - np.sum(w * w, 0), 0.0)
        return mean, var

    def signal_sigma(self) -> list[float]:
        """The residuals' standard deviation beyond the noise, per column (0: the model explains)."""
        return [math.sqrt(float(x)) for x in self._signal]
