"""One decision, one place: the Section-IV axes rounded relative to their step (the
same values as before on every default axis), the GA's automatic population from the
Rust core, and the registries' constants used by the signatures."""

from __future__ import annotations

import numpy as np
import pytest

from avll.paper import SECTION_IV_GRID, section_iv_axis

# every evenly spaced axis the registries, the CLI's defaults, the docs and the tests use
_AXES = [SECTION_IV_GRID["Tg"], SECTION_IV_GRID["kv"], SECTION_IV_GRID["kg"],
         (0.0, 15.0, 301), (0.0, 15.0, 31), (0.0, 1.0, 11), (0.0, 1.2, 25), (0.0, 1.0, 4)]


@pytest.mark.parametrize("axis", _AXES)
def test_even_axes_are_the_10_decimal_rounding_bit_for_bit(axis: tuple[float, float, int]
                                                          ) -> None:
    from avll.cli.stability_map import _range

    want = np.round(np.linspace(*axis), 10)
    assert section_iv_axis(*axis).tobytes() == want.tobytes()
    assert _range([f"{x:g}" for x in axis], "x").tobytes() == want.tobytes()


@pytest.mark.parametrize("first", [0.0, 1.0, 1000.0])
def test_fine_steps_are_never_merged(first: float) -> None:
    from avll.cli.stability_map import _range

    for x in (section_iv_axis(first, first + 1e-8, 11),
              _range([repr(first), repr(first + 1e-8), "11"], "kv")):
        assert np.unique(x).size == 11 and np.all(np.diff(x) > 0)
    np.testing.assert_array_equal(section_iv_axis(0.0, 1e-8, 11), np.arange(11) / 1e9)


def test_ga_automatic_population_is_the_cores(capsys: pytest.CaptureFixture[str]) -> None:
    from avll import PAPER_TABLE_II, _core, calibrate
    from avll.cli import build_parser
    from avll.synth import paper_experiment

    per, least = _core.GA_AUTO_POP
    assert [_core.ga_auto_pop(d) for d in range(9)] == [max(per * d, least) for d in range(9)]
    runs = paper_experiment(PAPER_TABLE_II["second"], seed=3, duration=20.0)[:2]
    auto, given = (calibrate("second", runs, seed=1, max_generations=3, starts=1, pop_size=p)
                   for p in (0, _core.ga_auto_pop(4)))  # the second model: 4 parameters
    assert (auto.evaluations, auto.cost, auto.params) == (given.evaluations, given.cost,
                                                          given.params)
    with pytest.raises(SystemExit):
        build_parser().parse_args(["calibrate", "--help"])
    assert f"0 is automatic: max({per} x parameters, {least}))" in " ".join(
        capsys.readouterr().out.split())


# a decision's value written again outside its registry
_WRITTEN_ONCE = [r"pade_orders?: [^=\n]*= \(?2\b", r"\blevel: float = 0\.95\b",
                 r"\"level\": 0\.95\b", r"Gmin: float = 9\.5\b",
                 r"_range: tuple\[float, float\] = \(",
                 r"(noise_[avx]|quantization_a): float = \d", r"duration: float = 180\b",
                 r"\(\"first\", \"second\", \"proposed\"\)"]


def test_registry_values_are_not_written_again() -> None:
    import re
    from pathlib import Path

    import avll
    from avll import defaults, models, paper, stability

    assert (paper.PADE_ORDER, paper.GMIN) == (2, 9.5) and defaults.LEVEL == 0.95
    assert paper.SECTION_IV_GRID["pade_order"] == paper.PADE_ORDER == models.PADE_ORDER
    assert models.UpperLevel(kg=0.5).Gmin == paper.GMIN
    assert stability.MIN_TG_BOX == {"kg": (1e-3, 2.0), "kv": (0.0, 1.2), "Tg": (0.0, 15.0)}
    assert stability.KV_SUP_BOX == {"kg": (1e-3, 5.0), "Tg": (0.0, 15.0), "kv": (0.0, 2.0)}
    assert (defaults.SYNTH_DURATION, defaults.SYNTH_DT) == (180.0, 0.05)
    assert defaults.SYNTH_NOISE == {"noise_a": 0.05, "noise_v": 0.02, "noise_x": 0.02,
                                    "quantization_a": 0.01}
    assert stability.DEFAULT_RANGES == {"kg": (1e-4, 10.0), "Tg": (0.0, 15.0), "kv": (-1.0, 2.0)}
    hits = [f"{p.name}: {m.group(0)}" for p in Path(avll.__file__).parent.rglob("*.py")
            for rx in _WRITTEN_ONCE for m in re.finditer(rx, p.read_text(encoding="utf-8"))]
    assert hits == ['paper.py: ("first", "second", "proposed")'], hits  # MODELS itself



def test_bootstraps_take_the_resample_count_of_intervals(monkeypatch: pytest.MonkeyPatch
                                                         ) -> None:
    """``avll.bootstrap`` and ``maps.bootstrap_distributed`` without ``n`` resample as
    many times as :class:`avll.Intervals` does by default: one decision."""
    import avll
    import avll.maps as maps
    import avll.uncertainty as uncertainty
    from avll.synth import paper_experiment

    default, sizes = uncertainty.Intervals().n, []

    class Stop(Exception):
        pass

    class Spy(uncertainty.Intervals):
        def __post_init__(self) -> None:
            sizes.append(self.n)
            raise Stop

    monkeypatch.setattr(uncertainty, "Intervals", Spy)
    runs = paper_experiment(runs=(1,), duration=10.0)
    for call in (avll.bootstrap, maps.bootstrap_distributed):
        with pytest.raises(Stop):
            call("first", runs)
    assert sizes == [default] * 2


def test_reproduce_builds_the_paper_grid_with_the_papers_axis() -> None:
    """``avll reproduce``'s default axes are :data:`SECTION_IV_GRID`'s, bit for bit."""
    from avll.reproduce import SETTINGS

    g = SECTION_IV_GRID
    want = (section_iv_axis(*g["kg"], log=True), section_iv_axis(*g["Tg"]),
            section_iv_axis(*g["kv"]))
    got = SETTINGS["default"].axes()
    assert [a.tobytes() for a in got] == [w.tobytes() for w in want]
