"""One registry of defaults: the GA options are the Rust core's (Python reads them, a
``None`` in a signature means them, the commands default to them), one closed-loop
objective weighting, and the paper's Section-IV grid defined once."""

from __future__ import annotations

import inspect
import math

import numpy as np
import pytest

from avll import _core
from avll.defaults import CLOSED_LOOP_WEIGHTS, DEFAULT_STARTS, GA_OPTIONS


def test_python_ga_options_are_the_rust_defaults() -> None:
    rust = _core.ga_defaults()
    assert GA_OPTIONS == rust and list(GA_OPTIONS) == list(rust)
    # the values the GA's documentation states (rust/optimize/ga.rs, GaOptions)
    assert rust["max_generations"] == 300 and rust["pop_size"] == 0
    assert rust["stall_generations"] == 20 and rust["polish"] is True
    # every default passes the core's own check unchanged, one option at a time too
    assert _core.ga_check() == rust
    for k, v in rust.items():
        assert _core.ga_check({k: v}) == rust, k
    assert _core.ga_check({"max_generations": 7})["max_generations"] == 7


@pytest.mark.parametrize(("options", "error", "match"), [
    ({"pop_size": 1}, ValueError, "pop_size: must be 0"),
    ({"pop_size": 2.0}, TypeError, "pop_size: must be an integer, got 2.0"),
    ({"max_generations": True}, TypeError, "max_generations: must be an integer"),
    ({"max_generations": -1}, ValueError, "max_generations: must be an integer in 0"),
    ({"tournament": 0}, ValueError, "tournament"),
    ({"stall_generations": 0}, ValueError, "stall_generations"),
    ({"crossover_prob": 2.0}, ValueError, "crossover_prob: must be in"),
    ({"mutation_prob": math.nan}, ValueError, "mutation_prob"),
    ({"ftol": math.inf}, ValueError, "ftol: must be finite"),
    ({"eta_c": 0.0}, ValueError, "eta_c"),
    ({"eta_m": "20"}, TypeError, "eta_m: must be a number"),
    ({"plus": 1}, TypeError, "plus: must be True or False"),
    ({"popsize": 3}, ValueError, "popsize: unknown GA option; known: pop_size, "),
])
def test_the_core_checks_the_ga_options(options: dict, error: type, match: str) -> None:
    with pytest.raises(error, match=match):
        _core.ga_check(options)


def test_numpy_values_are_accepted() -> None:
    out = _core.ga_check({"pop_size": np.int64(12), "ftol": np.float64(1e-3),
                          "polish": np.bool_(False)})
    assert (out["pop_size"], out["ftol"], out["polish"]) == (12, 1e-3, False)


def test_signatures_take_none_for_the_ga_budget() -> None:
    from avll.diagnose import effect_loop

    for fn in (effect_loop,):
        params = inspect.signature(fn).parameters
        for name in ("max_generations", "pop_size"):
            if name in params:
                assert params[name].default is None, f"{fn.__name__}({name}=...)"
    from avll.reproduce import SETTINGS, Settings

    assert Settings().max_generations == GA_OPTIONS["max_generations"]
    assert Settings().starts == DEFAULT_STARTS
    assert SETTINGS["default"] == Settings()


@pytest.mark.parametrize("argv", [
    ["calibrate", "d.csv"],
    ["diagnose", "d.csv", "--cal-runs", "1", "--json", "o.json"],
    ["study", "openacc", "d", "--out", "o"],
])
def test_the_commands_default_to_the_ga_options(argv: list[str]) -> None:
    from avll.cli import build_parser

    ns = build_parser().parse_args(argv)
    assert ns.max_generations == GA_OPTIONS["max_generations"]
    assert ns.starts == DEFAULT_STARTS
    if getattr(ns, "pop_size", None) is not None:
        assert ns.pop_size == GA_OPTIONS["pop_size"]


def test_one_closed_loop_weighting() -> None:
    from avll.diagnose import fitting
    from avll.studies import fielddata, openacc

    assert fitting.CLOSED_LOOP_WEIGHTS is CLOSED_LOOP_WEIGHTS
    assert fielddata.ASTAZERO_OBJECTIVES["mixed"] is CLOSED_LOOP_WEIGHTS
    assert tuple(openacc.WEIGHTS) == CLOSED_LOOP_WEIGHTS
    # the documented choice: 0.1 m/s², 0.1 m/s and 1 m errors cost the same
    wa, wv, wx = CLOSED_LOOP_WEIGHTS
    assert wa * 0.1**2 == pytest.approx(wv * 0.1**2) == pytest.approx(wx * 1.0**2)


def test_section_iv_grid_is_defined_once() -> None:
    from avll.paper import SECTION_IV_GRID as G
    from avll.paper import section_iv_axis
    from avll.reproduce import Settings

    kg, tg, kv = Settings().axes()
    np.testing.assert_array_equal(kg, section_iv_axis(*G["kg"], log=True))
    np.testing.assert_array_equal(tg, section_iv_axis(*G["Tg"]))
    np.testing.assert_array_equal(kv, section_iv_axis(*G["kv"]))
    assert tg[1] == 0.1 and kv[1] == 0.01  # decimal steps, as the paper states them
    s = Settings()
    assert (s.pade_order, s.kv_tg_step, s.kv_tol) == (G["pade_order"], G["kv_tg_step"],
                                                      G["kv_tol"])


def test_search_boxes_come_from_one_place() -> None:
    from avll.calibration import DEFAULT_BOUNDS, UPPER_BOUNDS, default_bounds
    from avll.effects import EFFECTS

    box = default_bounds("proposed", ("kg", "Gmin"), ("asymmetric", "delay"), "speed")
    assert list(box) == [*DEFAULT_BOUNDS["proposed"], "delay.tau", "asymmetric.kb",
                         "asymmetric.rb", "kg", "Gmin"]  # effects in canonical order
    assert box["asymmetric.kb"] == (1.0, 1.0, "linear")  # a speed command fixes it
    assert box["delay.tau"] == (*EFFECTS["delay"].bounds[0], "linear")
    assert box["Gmin"] == UPPER_BOUNDS["Gmin"]


def test_the_diagnosis_settings_come_from_the_effect_registry() -> None:
    from avll.diagnose.fitting import _fixed
    from avll.diagnose.signatures import _TRIALS_FROM_DATA, _effect_grid
    from avll.effects import EFFECTS

    for name, cls in EFFECTS.items():
        assert cls.signature in ("linear", "setting", "each", "scaled"), name
        for kind, fixed in cls.fixed.items():
            assert kind in ("acceleration", "speed") and set(fixed) <= set(cls.param_names())
        if cls.excludes is not None:  # refused together, both ways
            assert EFFECTS[cls.excludes].excludes == name
        for t in cls.trials:
            assert set(t) == set(cls.param_names()), name
        # a threshold effect's trials come from the data or from the class
        if cls.signature != "linear":
            assert cls.trials or name in _TRIALS_FROM_DATA, name
    assert _fixed("asymmetric", "kb", "speed") == 1.0
    assert _fixed("asymmetric", "kb", "acceleration") is None
    assert _effect_grid("grade", [], []) == [dict(t) for t in EFFECTS["grade"].trials]
