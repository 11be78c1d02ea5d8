"""The cross-validated residual loop: selection by folds of the
calibration runs, the three-way split, flags, "none of these", and the JSON contract
(``final_model`` -> ``avll.model_from_dict`` + ``avll.simulate_run`` reproduce the
reported test MSE).

Data: :func:`avll.synth_effects.paper_experiment_effects` (effects realised
differently from the library's); GA budgets are small (``max_generations=MAXITER``).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, replace

import numpy as np
import pytest

import avll
from avll.cli import main
from avll.diagnose import (
    at_bound,
    block_bootstrap_gain,
    effect_loop,
    loss_difference_test,
    make_folds,
    write_report,
)
from avll.diagnose.signatures import _effect_grid, diagnose
from avll.effects import EFFECTS, Asymmetric, WithEffects
from avll.io import write_runs
from avll.synth_effects import paper_experiment_effects

FIRST = avll.FirstOrderLag(Td=0.6)
SECOND = avll.PAPER_TABLE_II["second"]
MAXITER = 100
RUNS = (1, 3, 8, 12, 15, 19, 5)


def _strict(text: str) -> dict:
    def bad(tok: str) -> None:
        raise AssertionError(f"non-strict JSON token {tok}")

    return json.loads(text, parse_constant=bad)


@pytest.fixture(scope="module")
def rate_runs():
    # A jerk limit the first-order lag does not have (leader 3x brisker, as in
    # tests/test_diagnose.py).
    return paper_experiment_effects(FIRST, {"rate_limit": {"j": 1.0}}, seed=0,
                                    leader_speedup=3.0, runs=RUNS)  # fmt: skip


@pytest.fixture(scope="module")
def rate_result(rate_runs):
    return effect_loop("first", rate_runs[:3], rate_runs[3:5], test_runs=rate_runs[5:], seed=1,
                       max_generations=MAXITER)  # fmt: skip


# --- selection ----------------------------------------------------------------


def test_cv_accepts_the_known_effect(rate_result) -> None:
    res = rate_result
    assert [s.effect for s in res.steps][:1] == ["rate_limit"]
    s = res.steps[0]
    assert s.fold_selection >= 0.5
    assert s.cv.folds == 3 and s.cv.fold_kind == "runs"  # leave-one-run-out
    assert s.cv.gain >= res.settings.min_gain and s.p_value < res.settings.cv_alpha
    lo, hi = s.cv.boot.ci
    assert 0 < lo <= s.cv.gain <= hi
    d = s.to_dict()
    # Validation and test runs are reported, and the gain holds on both.
    assert d["val_mse_after"] < d["val_mse_before"]
    assert d["test_mse_after"] < d["test_mse_before"]
    assert "test_gain_not_held" not in s.flags
    # fold_selection is reported for every cross-validated candidate.
    assert all(0 <= t.fold_selection <= 1 and len(t.fold_gains) == 3 for t in res.trials)


def test_coloured_noise_only_accepts_nothing() -> None:
    # Clean lower level, AR(1) sensor noise (lag-1 correlation 0.95): no effect, and
    # no structure "no effect explains" either.
    runs = paper_experiment_effects(FIRST, {}, seed=0, noise_a=0.0, runs=RUNS[:6])
    noisy = []
    for k, r in enumerate(runs):
        rng = np.random.default_rng(100 + k)
        w = rng.normal(0, 0.05, r.a.size)
        e = np.zeros_like(w)
        for i in range(1, w.size):
            e[i] = 0.95 * e[i - 1] + w[i]
        noisy.append(replace(r, a=r.a + e))
    res = effect_loop("first", noisy[:3], noisy[3:4], test_runs=noisy[4:], seed=1,
                      max_generations=MAXITER)  # fmt: skip
    assert res.steps == []
    assert res.unexplained["structure_found"] is False
    assert res.unexplained["lag1_autocorrelation"] > 0.8  # the noise is coloured
    assert not any(f.kind == "structure_unexplained" for f in res.flags)


def test_min_gain_rejects_a_significant_small_gain() -> None:
    # A short transport delay on a first-order lag lowers the out-of-fold error by a few
    # per cent, significantly: accepted with a 2 % minimum, not with 50 %.
    runs = paper_experiment_effects(FIRST, {"delay": None}, seed=0, runs=RUNS[:4])
    low = effect_loop("first", runs[:3], runs[3:], seed=1, min_gain=0.02, max_effects=1,
                      max_generations=MAXITER)  # fmt: skip
    assert [s.effect for s in low.steps] == ["delay"]
    gain = low.steps[0].cv.gain
    assert 0.02 <= gain < 0.5 and low.steps[0].p_value < 0.01
    high = effect_loop("first", runs[:3], runs[3:], seed=1, min_gain=0.5, max_effects=1,
                       max_generations=MAXITER)  # fmt: skip
    assert high.steps == []
    rej = [r for r in high.rejected if r.effect == "delay"]
    assert rej and any("minimum" in why for why in rej[0].reasons)


# --- the split ------------------------------------------------------------------


def test_gain_that_does_not_hold_on_test_runs_is_flagged(tmp_path) -> None:
    # Calibration and validation runs on a graded track with the grade uncompensated;
    # the test runs record the same grade signal but the vehicle compensates it (the
    # truth has no grade term there): the effect's gain does not carry over, and the
    # JSON and the report say so.
    graded = paper_experiment_effects(FIRST, {"grade": None}, seed=0, runs=RUNS)
    clean = paper_experiment_effects(FIRST, {}, seed=0, runs=RUNS[5:])
    test = [replace(c, exo={"grade": g.exo["grade"]}) for c, g in zip(clean, graded[5:],
                                                                    strict=True)]  # fmt: skip
    res = effect_loop("first", graded[:3], graded[3:5], test_runs=test, seed=1,
                      max_generations=MAXITER, max_effects=1)  # fmt: skip
    assert [s.effect for s in res.steps] == ["grade"]
    d = res.to_dict()
    st = d["steps"][0]
    assert st["val_mse_after"] < st["val_mse_before"]  # validation agrees with the folds
    assert st["test_mse_after"] >= st["test_mse_before"]
    assert "test_gain_not_held" in st["flags"]
    assert any(f["kind"] == "test_gain_not_held" and f["step"] == 1 for f in d["flags"])
    assert d["splits"]["test_runs"] == ["19", "5"]
    text = write_report(res, tmp_path / "rep").read_text()
    assert "does not hold on the test runs" in text


def test_splits_must_be_disjoint(rate_runs) -> None:
    with pytest.raises(ValueError, match="test_runs: run '1' is also in cal_runs"):
        effect_loop("first", rate_runs[:3], test_runs=rate_runs[:1], max_generations=5)


def test_folds_are_deterministic() -> None:
    runs = paper_experiment_effects(FIRST, {}, seed=0, duration=20.0,
                                    runs=(1, 2, 3, 4, 5, 6, 7))  # fmt: skip
    f1, kind = make_folds(runs, None, seed=3)
    f2, _ = make_folds(runs, None, seed=3)
    assert kind == "runs" and len(f1) == 5
    held = [[r.run_id for r in h] for _, h in f1]
    assert held == [[r.run_id for r in h] for _, h in f2]
    assert sorted(i for h in held for i in h) == sorted(r.run_id for r in runs)
    for train, h in f1:
        assert not {r.run_id for r in train} & {r.run_id for r in h}
    loo, _ = make_folds(runs[:3], None, seed=3)
    assert [[r.run_id for r in h] for _, h in loo] == [["1"], ["2"], ["3"]]
    # One run: contiguous blocks.
    blocks, kind = make_folds(runs[:1], None, seed=0)
    assert kind == "blocks" and len(blocks) == 3
    n = sum(len(h[0]) for _, h in blocks)
    assert n == len(runs[0])
    with pytest.raises(ValueError, match="folds: a single calibration run"):
        make_folds(runs[:1], 100, seed=0)


def test_single_calibration_run_uses_blocks(rate_runs) -> None:
    res = effect_loop("first", rate_runs[:1], rate_runs[1:2], seed=1, max_generations=MAXITER,
                      max_effects=1)  # fmt: skip
    assert res.splits.fold_kind == "blocks" and len(res.splits.folds) == 3
    assert [s.effect for s in res.steps] == ["rate_limit"]
    assert res.steps[0].fold_selection > 0.5


# --- bounds, none of these ------------------------------------------------------------


def test_at_bound_flags() -> None:
    m = WithEffects(avll.FirstOrderLag(Td=3.0), (Asymmetric(kb=3.0, rb=1.0),))
    got = {a.param: a.bound for a in at_bound(m)}
    assert got == {"Td": "upper", "asymmetric.kb": "upper"}
    # Within the relative tolerance (0.1 % of the box) but not exactly at it.
    m = WithEffects(avll.FirstOrderLag(Td=0.01 + 1e-4), (Asymmetric(kb=1.0, rb=0.3 + 1e-3),))
    assert {a.param for a in at_bound(m)} == {"Td", "asymmetric.rb"}
    # A speed command fixes kb = 1: never "at bound".
    m = WithEffects(avll.SecondOrder(K0=1.0, m2=1.0, m3=1.0, Td=0.3), (Asymmetric(1.0, 1.0),))
    assert at_bound(m, kind="speed") == ()


def test_bound_flags_reach_json_and_report(rate_result, tmp_path) -> None:
    res = rate_result
    d = _strict(json.dumps(avll._atomic.json_safe(res.to_dict()), allow_nan=False))
    flagged = [(f["step"], p) for f in d["flags"] if f["kind"] == "at_bound" for p in f["params"]]
    expect = [(0, a.param) for a in res.baseline_at_bound] + [
        (k, a.param) for k, s in enumerate(res.steps, 1) for a in s.at_bound]
    assert sorted(flagged) == sorted(expect)
    for k, s in enumerate(d["steps"], 1):
        assert s["at_bound"] == [asdict(a) for a in res.steps[k - 1].at_bound]
    text = write_report(res, tmp_path / "rep").read_text()
    assert "recovered" not in text.lower()
    if expect:
        assert "at bound" in text.lower() or "at upper bound" in text or "at lower bound" in text


def test_none_of_these_with_evidence(tmp_path) -> None:
    # Uncompensated road load in the data, but the library is only offered effects
    # that cannot express it: nothing is accepted, and the residual's dependence is
    # reported with its evidence instead of a least-bad effect.
    runs = paper_experiment_effects(SECOND, {"speed_drag": None}, seed=0, runs=RUNS[:6])
    res = effect_loop("second", runs[:3], runs[3:4], test_runs=runs[4:], seed=1,
                      candidates=["delay", "deadband"], max_generations=MAXITER)  # fmt: skip
    assert res.steps == []
    un = res.unexplained
    assert un["structure_found"] is True
    assert un["message"].startswith("none of these")
    sig = {s["signal"]: s for s in un["signals"]}
    assert set(sig) == {"speed", "time in run", "command"}
    kept = [s for s in un["signals"] if s["keeps_structure"]]
    assert kept and un["unexplained_share"] == pytest.approx(max(s["explained"] for s in kept))
    for s in un["signals"]:
        assert len(s["centers"]) == len(s["means"]) == len(s["half_width"]) > 2
    assert any(f.kind == "structure_unexplained" for f in res.flags)
    text = write_report(res, tmp_path / "rep").read_text()
    assert "none of these" in text and (tmp_path / "rep" / "unexplained.png").exists()


@pytest.mark.slow
def test_road_load_found_when_offered() -> None:
    # The contrast to the case above: the whole library offered, the drag is found
    # (as speed_drag or as road_load, whose polynomial contains it).
    runs = paper_experiment_effects(SECOND, {"speed_drag": None}, seed=0, runs=RUNS[:4])
    full = effect_loop("second", runs[:3], runs[3:], seed=1, max_generations=MAXITER, max_effects=1)
    assert [s.effect for s in full.steps] in (["speed_drag"], ["road_load"])
    assert full.steps[0].fold_selection > 0.5


# --- statistics -------------------------------------------------------------------------


def _ar1(rng: np.random.Generator, n: int, phi: float = 0.9) -> np.ndarray:
    w = rng.normal(size=n)
    e = np.zeros(n)
    for i in range(1, n):
        e[i] = phi * e[i - 1] + w[i]
    return e


def test_bootstrap_and_ess_tests_respect_autocorrelation() -> None:
    # Same-variance AR(1) errors before and after: no reduction. A white-noise test
    # would call a large share "significant"; these tests keep the false-positive rate
    # near the level.
    rng = np.random.default_rng(0)
    pb, pt = [], []
    for _ in range(40):
        b = [_ar1(rng, 1500) for _ in range(2)]
        a = [_ar1(rng, 1500) for _ in range(2)]
        pb.append(block_bootstrap_gain(b, a, n_boot=400, seed=1).p_value)
        pt.append(loss_difference_test(b, a).p_value)
    assert np.mean(np.array(pb) < 0.05) <= 0.15
    assert np.mean(np.array(pt) < 0.05) <= 0.15
    # A real 30 % reduction is found.
    b = [_ar1(rng, 1500) for _ in range(2)]
    a = [x * math.sqrt(0.7) for x in b]
    r = block_bootstrap_gain(b, a, n_boot=400, seed=1)
    assert r.gain == pytest.approx(0.3) and r.p_value < 0.01
    assert r.ci[0] <= 0.3 <= r.ci[1] and r.block_length > 1
    assert loss_difference_test(b, a).p_value < 0.01


def test_every_registered_effect_has_signature_settings() -> None:
    # Generic over the registry: every effect (including ones added later) gets
    # settings inside its bounds that build the effect.
    runs = paper_experiment_effects(FIRST, {}, seed=0, duration=20.0, runs=(1,))
    sims = [r.a for r in runs]
    for name, cls in EFFECTS.items():
        grid = _effect_grid(name, runs, sims)
        assert grid, name
        for setting in grid:
            for p, (lo, hi) in zip(cls.param_names(), cls.bounds, strict=True):
                assert lo <= setting[p] <= hi, (name, p, setting)
            cls(**setting)


# --- the contract -----------------------------------------------------------------------


def test_contract_round_trip(tmp_path, capsys) -> None:
    graded = paper_experiment_effects(FIRST, {"grade": None}, seed=0, runs=RUNS)
    data = write_runs(graded, tmp_path / "runs.csv")
    out = tmp_path / "out.json"
    code = main(["diagnose", str(data), "--command-kind", "acceleration", "--model", "first",
                 "--cal-runs", "1,3,8", "--val-runs", "12,15", "--test-runs", "19,5",
                 "--seed", "1", "--max-generations", str(MAXITER), "--json", str(out), "--quiet",
                 "--report", str(tmp_path / "rep")])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    d = _strict(out.read_text())
    assert d["base_model"] == "first" and d["effects"] == [s["effect"] for s in d["steps"]]
    assert d["effects"], "the uncompensated grade should be accepted"
    assert d["splits"]["cal_runs"] == ["1", "3", "8"]
    assert d["splits"]["val_runs"] == ["12", "15"] and d["splits"]["test_runs"] == ["19", "5"]
    for st in d["steps"]:
        for k in ("val_mse_before", "val_mse_after", "test_mse_before", "test_mse_after",
                  "fold_selection"):
            assert isinstance(st[k], float), k
    m = avll.model_from_dict(d["final_model"])
    assert isinstance(m, WithEffects) and list(m.effect_names) == sorted(
        d["effects"], key=list(EFFECTS).index)
    assert avll.model_from_dict(d).to_array().tolist() == m.to_array().tolist()
    sim = d["final_model"]["simulation"]
    test = [r for r in avll.io.read_runs(data) if r.run_id in ("19", "5")]
    per_run = {r.run_id: float(np.mean((r.a - avll.simulate_run(
        m, r, init=sim["init"], closed_loop=sim["closed_loop"])) ** 2)) for r in test}
    last = d["steps"][-1]
    for rid, v in per_run.items():
        assert v == pytest.approx(last["test_mse_after_per_run"][rid], rel=1e-12)
    assert float(np.mean(list(per_run.values()))) == pytest.approx(last["test_mse_after"],
                                                                   rel=1e-12)
    # No effects: the plain base model.
    plain = avll.model_from_dict({**d["final_model"], "effects": []})
    assert isinstance(plain, avll.FirstOrderLag)
    with pytest.raises(ValueError, match="missing key 'base'"):
        avll.model_from_dict({"params": {}})
    assert "Test MSE" in (tmp_path / "rep" / "report.md").read_text()


def test_import_avll_stays_light() -> None:
    import subprocess
    import sys

    code = ("import sys, avll; print(','.join(m for m in ('pandas', 'scipy') "
            "if m in sys.modules)); avll.model_from_dict; avll.simulate_run; "
            "print('avll.diagnose.contract' in sys.modules)")  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split("\n")  # fmt: skip
    assert out[0] == ""
    assert out[1] == "True"  # the contract functions load on first use


def test_cli_refuses_overlapping_splits(tmp_path, capsys) -> None:
    runs = paper_experiment_effects(FIRST, {}, seed=0, duration=20.0, runs=(1, 3, 8))
    data = write_runs(runs, tmp_path / "runs.csv")
    code = main(["diagnose", str(data), "--model", "first", "--cal-runs", "1,3",
                 "--test-runs", "3,8", "--json", str(tmp_path / "o.json"), "--quiet"])  # fmt: skip
    assert code == 2
    err = capsys.readouterr().err
    assert "--test-runs: run(s) 3 are also in --cal-runs" in err and "Traceback" not in err
    assert not (tmp_path / "o.json").exists()


def test_contract_round_trip_closed_loop() -> None:
    # No command, unknown upper law (as AstaZero): the loop calibrates the law, which
    # final_model carries; simulate_run with it reproduces every reported MSE.
    runs = paper_experiment_effects(FIRST, {}, seed=0, duration=40.0, runs=(1, 3, 8, 12))
    runs = [replace(r, command=None, upper=None) for r in runs]
    res = effect_loop("first", runs[:2], runs[2:3], test_runs=runs[3:], seed=1, max_generations=30,
                      max_effects=1)  # fmt: skip
    d = _strict(json.dumps(avll._atomic.json_safe(res.to_dict()), allow_nan=False))
    fm = d["final_model"]
    assert fm["simulation"]["closed_loop"] is True and fm["upper"] is not None
    m = avll.model_from_dict(d)
    up = avll.UpperLevel(**fm["upper"])
    for key, rs in (("cal", runs[:2]), ("val", runs[2:3]), ("test", runs[3:])):
        if d["steps"]:
            want = d["steps"][-1][f"{key}_mse_after_per_run"]
        else:
            want = d["baseline_mse"][key]["per_run"]
        for r in rs:
            got = float(np.mean((r.a - avll.simulate_run(m, r, upper=up)) ** 2))
            assert got == pytest.approx(want[r.run_id], rel=1e-12), (key, r.run_id)


def test_report_shows_what_the_effects_do_to_stability(rate_result, tmp_path) -> None:
    """The report of a loop that accepted an effect evaluates the
    baseline fit and the final model with its effects, linearised and in a
    time-domain platoon, under the reference upper law (a recorded command)."""
    from avll.diagnose.report import REFERENCE_UPPER, stability_section

    sec = stability_section(rate_result, v0=12.0)
    assert sec is not None and sec["upper"] == REFERENCE_UPPER
    base, final = sec["baseline"], sec["final"]
    assert final.effects == tuple(rate_result.final.effect_names) and base.effects == ()
    # the baseline is linear: its amplification does not depend on the amplitude and
    # equals |H(jw)| of its linearisation at the disturbance frequency
    mb = base.mean_amplification()
    assert np.all(np.isfinite(mb))
    assert np.ptp(mb) < 1e-3 * mb[0]
    text = write_report(rate_result, tmp_path / "rep").read_text()
    assert "What the accepted effects do to stability" in text
    assert "reference law" in text and (tmp_path / "rep" / "stability.png").exists()


def test_cli_globs_threads_and_log_progress(tmp_path, capsys) -> None:
    # Run selections take glob patterns (shared with the other commands); with stderr
    # not a terminal the default progress is plain "avll:" lines without escape codes,
    # and every fit's stage ends at 100 %.
    runs = paper_experiment_effects(FIRST, {}, seed=0, duration=20.0, runs=(1, 3, 8, 12))
    runs = [replace(r, run_id=f"day{i // 2}/{r.run_id}") for i, r in enumerate(runs)]
    data = write_runs(runs, tmp_path / "runs.csv")
    out = tmp_path / "o.json"
    code = main(["diagnose", str(data), "--model", "first", "--cal-runs", "day0/*",
                 "--test-runs", "day1/1?", "--json", str(out), "--max-generations", "5",
                 "--max-effects", "0", "--threads", "1"])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 0, err
    d = json.loads(out.read_text())
    sp = d["splits"]
    assert sp["cal_runs"] == ["day0/1", "day0/3"]
    assert sp["test_runs"] == ["day1/12"] and sp["val_runs"] == ["day1/8"]
    assert "\x1b" not in err and "\r" not in err
    lines = [ln for ln in err.splitlines() if ln.startswith("avll: fit first")]
    assert lines and all("100%" in ln for ln in lines if ": done " in ln)
    assert any(": done 100%" in ln for ln in lines)
    assert "avll: diagnose: baseline" in err


def test_cli_json_is_required_and_patterns_must_match(tmp_path, capsys) -> None:
    runs = paper_experiment_effects(FIRST, {}, seed=0, duration=20.0, runs=(1, 3))
    data = write_runs(runs, tmp_path / "runs.csv")
    with pytest.raises(SystemExit) as e:
        main(["diagnose", str(data), "--cal-runs", "1"])
    assert e.value.code == 2 and "--json" in capsys.readouterr().err
    code = main(["diagnose", str(data), "--cal-runs", "x*", "--json",
                 str(tmp_path / "o.json"), "-q"])  # fmt: skip
    assert code == 2
    assert "--cal-runs: pattern 'x*' matches no run" in capsys.readouterr().err
    assert not (tmp_path / "o.json").exists()


def test_result_objects_plot(rate_result) -> None:
    # .plot() on the loop's result and on a diagnosis: matplotlib Figures from
    # avll.plotting (no pyplot state), one panel per binned signal.
    from matplotlib.figure import Figure

    fig = rate_result.plot()
    assert isinstance(fig, Figure)
    n = len(rate_result.unexplained.get("signals", []))
    assert len([ax for ax in fig.axes if ax.get_visible()]) == max(n, 1)
    figs = dict(rate_result.diagnoses[0].plot())
    assert set(figs) == {"residual_vs_signals", "residual_spectrum"}
    assert all(isinstance(f, Figure) for f in figs.values())


def test_at_bound_uses_the_upper_box_the_fit_searched() -> None:
    # A study that searched Gmin in [0, 4] m must call Gmin = 4 "at bound", which the
    # default box (wider) would not.
    from avll.diagnose import UPPER_BOUNDS, at_bound
    from avll.models import UpperLevel

    m = WithEffects(avll.PAPER_TABLE_II["second"], ())
    up = UpperLevel(0.2, 0.3, 1.5, 4.0)
    assert UPPER_BOUNDS["Gmin"][1] > 4.0
    assert at_bound(m, up) == ()
    hit = at_bound(m, up, upper_bounds={"Gmin": (0.0, 4.0)})
    assert [(e.param, e.bound) for e in hit] == [("upper.Gmin", "upper")]


def test_diagnose_runs_shorter_than_the_autocorrelation_window() -> None:
    # Runs of 150 and 180 samples (CARMA's short stretches are ~150): the residual's
    # autocorrelation is taken up to the shortest run's length (it used to ask one lag
    # more and fail with a broadcasting error).
    runs = paper_experiment_effects(FIRST, {}, seed=0, duration=20.0, runs=(1, 3))
    short = [r.cut(0, k, f"[0:{k}]") for r, k in zip(runs, (150, 180), strict=True)]
    d = diagnose(WithEffects(FIRST, ()), short)
    assert d.autocorr.size == 150 and d.autocorr[0] == pytest.approx(1.0)
    assert np.all(np.isfinite(d.xcorr))
