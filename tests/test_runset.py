"""avll.RunSet: packed once, views share the packed arrays, one calibration entry takes
it, and the effect loop packs its runs once."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import avll
from avll import _core
from avll.synth import paper_experiment
from avll.synth_effects import paper_experiment_effects

FIRST = avll.FirstOrderLag(Td=0.6)


@pytest.fixture(scope="module")
def runs() -> list[avll.Run]:
    return paper_experiment(FIRST, seed=3, runs=(1, 3, 8, 12), duration=30.0)


def test_packed_once_with_every_column(runs: list[avll.Run]) -> None:
    rs = avll.RunSet(runs)
    assert len(rs) == 4 and rs.run_ids == tuple(r.run_id for r in runs)
    assert list(rs) == runs and rs[1] is runs[1]
    # every column all runs have, not only what one cost needs
    assert {"command", "v", "x"} <= rs.columns
    assert rs.has("lead_x") == all(r.lead_x is not None for r in runs)
    assert rs.offsets == [0, *np.cumsum([len(r) for r in runs]).tolist()]
    assert rs.total == sum(len(r) for r in runs)


def test_subsets_are_views_on_the_same_arrays(runs: list[avll.Run]) -> None:
    rs = avll.RunSet(runs)
    sub = rs.subset([runs[2].run_id, 0, 0])
    assert sub.shares(rs) and rs[1:3].shares(rs)
    assert sub.run_ids == (runs[2].run_id, runs[0].run_id, runs[0].run_id)
    assert sub.handle.index == [2, 0, 0]
    assert sub.total == len(runs[2]) + 2 * len(runs[0])
    assert not avll.RunSet(runs).shares(rs)
    # the Rust costs of a view equal those of the runs packed on their own
    row = FIRST.to_array()[None, :]
    np.testing.assert_array_equal(
        avll.batch_cost("first", row, sub, effects=[]),
        avll.batch_cost("first", row, [runs[2], runs[0], runs[0]]))
    with pytest.raises(ValueError, match="subset: unknown run 'nope'"):
        rs.subset(["nope"])
    with pytest.raises(ValueError, match="subset: run index 4 is out of range"):
        rs.subset([4])
    with pytest.raises(ValueError, match="indices: run index 9 is out of range"):
        rs.handle.take([9])


def test_missing_columns_are_named_when_a_cost_needs_them(runs: list[avll.Run]) -> None:
    rs = avll.RunSet([runs[0], replace(runs[1], command=None)])
    assert not rs.has("command")  # packed without it: fine until a cost needs it
    with pytest.raises(ValueError, match=f"run '{runs[1].run_id}': column 'command' is missing"):
        avll.calibrate("first", rs, max_generations=2)
    no_law = avll.RunSet([runs[0], replace(runs[1], upper=None)])
    with pytest.raises(ValueError, match=f"run '{runs[1].run_id}': closed loop needs its "
                                         "upper-level law"):
        no_law.cost_kw(closed_loop=True)
    no_law.cost_kw(closed_loop=True, upper_free=[0, 1, 2, 3])  # all four gains calibrated
    with pytest.raises(TypeError, match="runs: expected a sequence of avll.Run"):
        avll.RunSet(runs[0])  # type: ignore[arg-type]


def test_one_calibration_entry(runs: list[avll.Run]) -> None:
    rs = avll.RunSet(runs)
    kw = dict(seed=4, max_generations=30, starts=1)
    a, b = avll.calibrate("first", runs, **kw), avll.calibrate("first", rs, **kw)
    assert a.params == b.params and a.per_run_mse == b.per_run_mse
    many = avll.calibrate("first", rs, subsets=[[0, 1], [2, 3]], **kw)
    same = avll.calibrate_many("first", runs, [[0, 1], [2, 3]], **kw)
    assert [m.params for m in many] == [s.params for s in same]
    assert list(many[1].per_run_mse) == [runs[2].run_id, runs[3].run_id]
    # a model with effects: the same result type, the effects' parameters by name
    second = avll.SecondOrder(K0=0.9, m2=0.3, m3=1.0, Td=0.25)
    sat = paper_experiment_effects(second, {"saturation": None}, seed=0, runs=(1, 3))
    r = avll.calibrate("second", sat, effects=["saturation"], seed=1, max_generations=40,
                       starts=1)
    assert isinstance(r, avll.CalibrationResult) and r.with_effects is not None
    assert r.with_effects.effect_names == ("saturation",)
    assert [k for k in r.params if k.startswith("saturation.")] == [
        "saturation.a_max", "saturation.d_max"]
    assert r.x is not None and len(r.x) == len(r.bounds) and r.intervals is None
    np.testing.assert_allclose(r.with_effects.to_array(), r.x)


def test_effect_loop_packs_its_runs_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """One _core.RunSet per effect_loop call: folds, candidates, validation and test
    runs are views on it (146 constructions for this call before the loop took a
    RunSet)."""
    runs = paper_experiment_effects(FIRST, {"delay": None}, seed=0, runs=(1, 3, 8, 12))
    built: list[int] = []
    real = _core.RunSet

    def counting(offsets: list[int], *a: object, **k: object) -> object:
        built.append(len(offsets) - 1)
        return real(offsets, *a, **k)  # type: ignore[arg-type]

    monkeypatch.setattr(_core, "RunSet", counting)
    from avll.diagnose import effect_loop

    res = effect_loop("first", runs[:2], runs[2:3], test_runs=runs[3:], seed=1,
                                    max_effects=1, tries=1, max_generations=8, starts=1,
                                    n_boot=50)  # fmt: skip
    assert built == [4]  # 2 calibration + 1 validation + 1 test run, packed once
    assert res.trials  # the folds and a candidate were cross-validated on it


def test_batched_calls_take_a_runset_without_packing_it_again(
        runs: list[avll.Run], monkeypatch: pytest.MonkeyPatch) -> None:
    rs = avll.RunSet(runs)
    params = np.array([[0.6], [0.9], [1.3]])
    by_list = avll.batch_cost("first", params, runs)
    built = []
    real = _core.RunSet
    monkeypatch.setattr(_core, "RunSet", lambda *a, **k: built.append(1) or real(*a, **k))
    by_set = avll.batch_cost("first", params, rs)
    from avll.rollout import simulate_batch

    sims = simulate_batch("first", params[:1], rs)
    assert built == [], "a RunSet was packed again"
    np.testing.assert_array_equal(by_set, by_list)
    assert np.isfinite(by_set).all() and len(sims.a) == len(rs)
