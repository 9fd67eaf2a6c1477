"""How the fit reads its starts (prsm_sim.identify.solve.disagreeing_starts), on closed-form problems.

Oracles: for residuals linear in the parameter the Wald interval (value ± 1.96 σ from the Jacobian) and the
profile-likelihood interval (Δχ² ≤ 3.84) are the same set, so no start can end outside the one and inside the
other: nothing is flagged (the limit case). A residual even about u = 0.5 has two minima of equal cost at
0.5 ± 0.2: a start ending at the other one is a second answer the data cannot tell apart. A residual with an
alternating part of five resolutions, which no value of the parameter removes (it is orthogonal to the
parameter's effect), misses the data by √26 resolutions RMS at its best, more than noise explains.
"""

from __future__ import annotations

import numpy as np

from prsm_sim.identify.free import FreeParameter
from prsm_sim.identify.solve import StartResult, covariance, disagreeing_starts, jacobian

N = 200
NOISE = np.random.default_rng(7).standard_normal(N)  # one resolution of noise per sample


class _Toy:
    """A fit problem of one parameter in [0, 1] whose residuals (in resolutions) are `law(u) + noise`."""

    def __init__(self, law):
        self.free = (FreeParameter(name="toy.x", unit="1", lower=0.0, upper=1.0),)
        self._law = law

    def residuals(self, u) -> np.ndarray:
        return self._law(float(np.asarray(u)[0])) + NOISE


def _flags(problem: _Toy, at: float, ends: list[float]) -> dict[str, str]:
    u = np.array([at])
    r0 = problem.residuals(u)
    C = covariance(jacobian(problem, u, r0), r0, np.arange(N))
    starts = [StartResult(u0=(0.5,), u=(e,), cost=0.0, nfev=1) for e in ends]
    return disagreeing_starts(problem, u, r0, C, starts)


def test_a_linear_residual_never_flags_a_start():
    toy = _Toy(lambda x: 10.0 * (x - 0.3))
    best = 0.3 - float(np.mean(NOISE)) / 10.0  # the least-squares point of the linear problem
    assert _flags(toy, best, list(np.linspace(0.0, 1.0, 41))) == {}


def test_two_minima_of_equal_cost_are_several_answers():
    toy = _Toy(lambda x: 40.0 * ((x - 0.5) ** 2 - 0.04))
    why = _flags(toy, 0.3, [0.7, 0.31])
    assert list(why) == ["toy.x"] and "several answers" in why["toy.x"] and "0.7" in why["toy.x"], why
    assert _flags(toy, 0.3, [0.31]) == {}  # a start that ended inside the interval says nothing new


def test_a_fit_that_misses_its_recordings_flags_every_disagreement():
    unexplained = 5.0 * (-1.0) ** np.arange(N)
    toy = _Toy(lambda x: 10.0 * (x - 0.3) + unexplained)
    best = 0.3 - float(np.mean(NOISE)) / 10.0
    assert _flags(_Toy(lambda x: 10.0 * (x - 0.3)), best, [0.9]) == {}  # the same start, data it reproduces
    why = _flags(toy, best, [0.9])
    assert "no start reproduced the recordings" in why["toy.x"], why
