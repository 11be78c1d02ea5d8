"""Synthetic platoons with structures hidden in the followers' upper level
(:class:`avll.synth_platoon.HiddenUpper`, the generator's own law in
``rust/sim/synth.rs``): the law, its small-signal truth, the generator's handling, and
the blind test of the library's upper-level structures on them (slow)."""

from __future__ import annotations

import numpy as np
import pytest

import avll
from avll import _core
from avll.effect_stability import frequency_response
from avll.effects import Perception, WithEffects
from avll.synth_platoon import CarTruth, HiddenUpper, synth_platoon, validate_structure

BASE = avll.PAPER_TABLE_II["proposed"]
UP = avll.UpperLevel(kg=0.15, kv=0.4, Tg=1.5, Gmin=3.0)
FINE = 0.01


def _sine_leader(f: float, amp: float, v0: float = 20.0, duration: float = 500.0
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = np.arange(int(duration / FINE)) * FINE
    ramp = np.where(t < 30, 0.5 * (1 - np.cos(np.pi * t / 30)), 1.0)
    lv = v0 + amp * ramp * np.sin(2 * np.pi * f * t)
    lx = 500.0 + np.concatenate([[0.0], np.cumsum(0.5 * FINE * (lv[1:] + lv[:-1]))])
    return t, lx, lv


def _run(h: HiddenUpper, lx: np.ndarray, lv: np.ndarray, phase: float = 0.0
         ) -> tuple[np.ndarray, ...]:
    gap = UP.Gmin + UP.Tg * lv[0]
    return _core.synth_closed_loop(BASE.name, BASE.values(), lx, lv, FINE, UP.kg, UP.kv, UP.Tg,
                                   UP.Gmin, float(lv[0]), float(lx[0] - gap), h.row(phase))


def test_neutral_hidden_law_is_eq3() -> None:
    _, lx, lv = _sine_leader(0.05, 1.0, duration=200.0)
    a, v, x, u = _run(HiddenUpper(), lx, lv)
    want = avll.closed_loop(BASE, lx, lv, FINE, UP, v0=float(lv[0]),
                            x0=float(lx[0] - UP.Gmin - UP.Tg * lv[0]))  # fmt: skip
    for got, w in ((a, want.a), (v, want.v), (x, want.x), (u, want.command)):
        np.testing.assert_allclose(got, w, rtol=0, atol=1e-12)


@pytest.mark.parametrize("hidden", [
    HiddenUpper(radar_period=0.1, radar_latency=0.3),
    HiddenUpper(ff_gain=0.6, ff_window=1.5),
    HiddenUpper(ratio=1.8, width_gap=0.5, width_speed=0.1),
    HiddenUpper(radar_period=0.066, radar_latency=0.25, ff_gain=0.4, ff_window=1.0, ratio=1.5),
], ids=["radar", "feedforward", "asymmetry", "all"])
def test_truth_response_is_the_simulated_amplification(hidden: HiddenUpper) -> None:
    """The generator's small-signal truth (:meth:`HiddenUpper.response`) is the steady
    amplitude ratio of its own law behind a sinusoidal leader. The asymmetry's average
    slope ``(1 + r)/2`` is the describing function of its odd part (exact for a
    sinusoid); its even part makes a mean shift and even harmonics, which in a closed
    loop return through the law into the fundamental: an error of the order
    ``((r - 1)/(r + 1))^2``, the tolerance used for it."""
    for f in (0.03, 0.1):
        t, lx, lv = _sine_leader(f, 0.5)
        _, v, _, _ = _run(hidden, lx, lv, phase=0.037)
        keep = t > 200
        xm = np.column_stack([np.ones(keep.sum()), np.sin(2 * np.pi * f * t[keep]),
                              np.cos(2 * np.pi * f * t[keep])])  # fmt: skip

        def amp(y: np.ndarray, xm: np.ndarray = xm, keep: np.ndarray = keep) -> float:
            c = np.linalg.lstsq(xm, y[keep], rcond=None)[0]
            return float(np.hypot(c[1], c[2]))

        h = abs(hidden.response(BASE, UP, [2 * np.pi * f], v=20.0, fine_dt=FINE)[0])
        plain = abs(frequency_response(BASE, UP, [2 * np.pi * f])[0])
        q = (hidden.ratio - 1) / (hidden.ratio + 1)
        # the radar's hold is a describing approximation; the rest is exact, the
        # generator's own hold at fine_dt included (half a period of dead time)
        tol = max(5e-3 if hidden.radar_period > 0 else 1e-5, q * q)
        assert amp(v) / amp(lv) == pytest.approx(h, rel=tol)
        assert abs(h / plain - 1) > 0.01, "the structure must change |H|"


def test_platoon_with_a_hidden_structure() -> None:
    h = HiddenUpper(radar_period=0.1, radar_latency=0.3, ff_gain=0.4, ratio=1.5)
    kw = dict(duration=200.0, warmup=40.0, models=("proposed",))
    pl = synth_platoon(3, seed=5, hidden=h, **kw)
    again = synth_platoon(3, seed=5, hidden=h, **kw)
    plain = synth_platoon(3, seed=5, **kw)
    np.testing.assert_array_equal(pl.v, again.v)
    assert np.max(np.abs(pl.v[1:] - plain.v[1:])) > 1e-2
    for tr, tp in zip(pl.truth, plain.truth, strict=True):
        assert tr["hidden"]["radar_latency"] == 0.3 and tp["hidden"] is None
        assert tr["params"] == tp["params"] and tr["upper"] == tp["upper"]
        assert tr["band_gain"] != tp["band_gain"]
    with pytest.raises(ValueError, match="hidden"):
        CarTruth(BASE, UP, effects=(Perception(0.2),), hidden=h)
    with pytest.raises(ValueError, match="ratio"):
        HiddenUpper(ratio=0.0)
    with pytest.raises(ValueError, match="hidden.radar_phase"):
        _core.synth_closed_loop(BASE.name, BASE.values(), np.zeros(5), np.zeros(5), FINE, 0.1,
                                0.1, 1.0, 2.0, 0.0, -2.0, [0.1, 0.5, 0, 0, 1, 1, 1, 1])
    with pytest.raises(ValueError, match="hidden law replaces"):
        h.response(WithEffects(BASE, (Perception(0.1),)), UP, [0.1], v=20.0, fine_dt=FINE)


@pytest.mark.slow
@pytest.mark.long
def test_blind_upper_structures_on_hidden_platoons() -> None:
    """The blind test (fresh seeds, the default GA budget): a hidden radar latency,
    windowed feedforward and smooth closing asymmetry bias the base model as on real
    platoons -- its predicted amplification low (most cars, and on average) and its
    Tg + Gmin/v̄ long (the asymmetry shifts the mean gap); base + the candidate
    structures (perception, closing, feedforward) reads Tg + Gmin/v̄ within the
    study's target (5 % for the median car, and closer than the base) and predicts the
    held-out third of each run better. Measured, not asserted (the study's targets
    for the final model's amplification, mean error within 1.5 % and 90 % of cars
    within 5 %, are not met by this fit): the structures leave the amplification
    bias about where the base has it (see ``docs/guide/blind-tests.md``). Those numbers
    were measured before the predictions evaluated the sampled loop (``hold=dt``,
    91f78c4) and have not been measured again since; the study's own selection, which
    meets the targets, is ``test_blind_selection_removes_the_amplification_bias``."""
    hid = HiddenUpper(radar_period=0.1, radar_latency=0.3, ff_gain=0.5, ff_window=1.5,
                      ratio=1.5)
    r = validate_structure([201, 202], hidden=hid, candidates=["perception", "closing",
                                                                "feedforward"],
                           cars=5, seed=1)  # fmt: skip
    assert r.base.mean_error < 0 and r.base.underestimated > 0.5
    assert r.base.time_gap_median_error > 0
    assert abs(r.candidates.time_gap_median_error) < abs(r.base.time_gap_median_error)
    assert r.candidates.time_gap_median_abs_error < 0.05
    assert r.candidates.heldout_change < 0


@pytest.mark.slow
@pytest.mark.long
def test_blind_null_structures_add_nothing() -> None:
    """Nothing hidden (fresh seeds): the candidate structures do not predict the
    held-out data better than the base model (within 1 % for the median car). Measured,
    not asserted: their parameters do not come out neutral (``perception`` trades with
    the lower level's dead time, ``closing.rg`` is weakly identified)."""
    r = validate_structure([203, 204], hidden=None, candidates=["perception", "closing",
                                                                 "feedforward"],
                           cars=5, seed=1)  # fmt: skip
    assert r.candidates.heldout_change > -0.01


#: The blind test of the study's selection: fresh seeds (never run while the selection
#: was developed, on seeds 1-3), 4 cars x 3 files of 300 s each, GA 100 generations.
BLIND_KW = dict(cars=4, files=3, max_generations=100, starts=1, duration=300.0)
BLIND_HIDDEN = HiddenUpper(radar_period=0.1, radar_latency=0.3, ff_gain=0.5, ff_window=1.5,
                           ratio=1.5)


@pytest.fixture(scope="module")
def blind_selection():  # type: ignore[no-untyped-def]
    from avll.synth_platoon import validate_selection

    return validate_selection([301, 302], hidden=BLIND_HIDDEN, **BLIND_KW)


@pytest.mark.slow
@pytest.mark.long
def test_blind_selection_finds_structure_and_fixes_the_time_gap(blind_selection) -> None:  # type: ignore[no-untyped-def]
    """What holds on the fresh seeds: the base model underestimates the amplification
    of most held-out files and reads ``Tg + Gmin/v̄`` long; the study's selection
    accepts structures out of sample and its final model reads ``Tg + Gmin/v̄``
    within 5 % for the median car."""
    r = blind_selection
    assert r.base.mean_error < 0 and r.base.underestimated > 0.5
    assert r.base.time_gap_median_error > 0
    assert r.with_structures > 0.5
    assert r.final.time_gap_median_abs_error < 0.05
    assert abs(r.final.time_gap_median_error) < abs(r.base.time_gap_median_error)


@pytest.mark.slow
@pytest.mark.long
def test_blind_selection_removes_the_amplification_bias(blind_selection) -> None:  # type: ignore[no-untyped-def]
    """The issue's amplification targets for the final model (mean error within
    1.5 %, at least 90 % of held-out files within 5 %). Measured (seeds 301, 302, 24
    held-out files, at 91f78c4): base mean -2.2 %, median -2.1 %, 91.7 % within 5 %,
    79 % underestimated, ``Tg + Gmin/v̄`` median +2.8 %; final mean -0.3 %, median
    +0.1 %, 95.8 % within 5 %, 50 % underestimated, ``Tg + Gmin/v̄`` median +0.15 %.
    Accepted: closing for every file, perception for 18 of 24, speed_gains for 3; the
    one file outside 5 % is the car of largest gain (true band gain 2.58: -8.1 % ->
    -8.5 %). Before the predictions evaluated the sampled loop the model was calibrated
    as (``hold=dt``, ``docs/guide/amplification.md``), the same seeds gave base -6.0 %,
    final -4.4 % and 62.5 % within 5 %: most of the bias this test measured was the
    hold's half sample of dead time, missing from every prediction. Selection cost:
    640 s for both seeds (one process, the shared 2-core machine)."""
    r = blind_selection
    assert abs(r.final.mean_error) <= 0.015 and r.final.within_5pct >= 0.9


@pytest.mark.slow
@pytest.mark.long
def test_blind_selection_adds_nothing_when_nothing_is_hidden() -> None:
    """Nothing hidden (a fresh seed): the selection accepts nothing, so the final model
    is the base model. Measured (seed 303, 12 held-out files, at 91f78c4): no
    structure accepted; base = final mean amplification error -1.0 % (-1.6 % with the
    continuous loop's predictions), 12 of 12 within 5 %, ``Tg + Gmin/v̄`` median error
    -0.03 %; 130 s on the shared 2-core machine."""
    from avll.synth_platoon import validate_selection

    r = validate_selection([303], hidden=None, **BLIND_KW)
    assert r.with_structures <= 0.25
    assert abs(r.final.mean_error - r.base.mean_error) < 0.01
