"""The resample refits of the intervals converge: warm-started at the full-data optimum,
each refit leaves it (the first simplexes around the optimum are all worse, so a stall
window counted from the start stopped every refit at the start itself: intervals of
width zero) and ends where a refit with a far larger budget ends (the simplex), or,
capped at ``avll.uncertainty.LM_BUDGET_PER_PARAM d`` rollouts (the Levenberg-Marquardt
refits: a k-step bootstrap), gains at least 90 % of what that refit gains."""

from __future__ import annotations

import numpy as np
import pytest

import avll
import avll.uncertainty as U
from avll import _core
from avll.synth import paper_experiment


def _refits(monkeypatch: pytest.MonkeyPatch, **opts: object) -> dict:
    got: dict = {}
    orig = _core.refit_resamples

    def spy(*a: object, **k: object) -> list:
        out = orig(*a, **k)
        got.update(out[0])
        return out

    monkeypatch.setattr(U._core, "refit_resamples", spy)
    runs = paper_experiment(avll.PAPER_TABLE_II["proposed"], seed=1)[:3]
    avll.calibrate("proposed", runs, seed=0, intervals=avll.Intervals(n=6, seed=3, **opts))
    return got


@pytest.mark.parametrize("refit", ["lm", "simplex"])
def test_refits_leave_the_optimum_and_reach_a_long_refits_values(
        monkeypatch: pytest.MonkeyPatch, refit: str) -> None:
    d = _refits(monkeypatch, refit=refit)
    f, f0 = np.asarray(d["f"]), np.asarray(d["f_x0"])
    x = np.asarray(d["x"])
    assert np.all(f <= f0)
    assert np.sum(f < f0 * (1 - 1e-6)) >= 5, (f, f0)   # they move
    assert np.all(np.ptp(x, axis=0) > 0), x            # a spread in every parameter
    long = _refits(monkeypatch, budget=20_000, refit=refit)
    fl = np.asarray(long["f"])
    if refit == "simplex":
        # the default budget stops where a 20,000-evaluation refit stops, to 2e-5 of the
        # cost (the resamples' gains on the optimum are 1e-4 to 1e-3 of it)
        assert np.all(np.abs(f - fl) <= 2e-5 * fl), (f, fl)
    else:
        # the k-step refits: at least 90 % of the long refit's gain on the optimum, and
        # most of them end where it ends
        assert np.all(f0 - f >= 0.9 * (f0 - fl)), (f, fl, f0)
        assert np.sum(np.abs(f - fl) <= 2e-5 * fl) >= 4, (f, fl)
