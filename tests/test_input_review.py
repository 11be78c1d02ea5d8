"""Bad inputs an outside review found escaping as the wrong exception, naming no
argument, or pointing at the wrong line: each is now a ValueError/TypeError (or a
DataError) that names the argument, the file and the physical line."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

import avll
from avll.io.canonical import load_canonical

M = avll.FirstOrderLag(0.5)
BIG = 10**400  # an int beyond the float range
RUNS = avll.synth.paper_experiment(runs=(1,), duration=4.0)


@pytest.mark.parametrize(("call", "match"), [
    (lambda: avll.simulate(M, [0, BIG], 0.1), "command: expected an array of numbers"),
    (lambda: avll.batch_cost("first", [[BIG]], RUNS), "params: expected an array of numbers"),
    (lambda: avll.stability_map(M, [BIG], [1], [0]), "kg: expected an array of numbers"),
    (lambda: avll.FirstOrderLag(BIG), "Td: must be finite"),
    (lambda: avll.FirstOrderLag.from_array([BIG]), "params: expected numbers"),
    (lambda: avll.Run("r", [0, .1, .2], a=[0, 0, BIG]), "run 'r': column 'a' must be numbers"),
    (lambda: avll.stable_intervals(M, "tg", kg=BIG, kv=.5), "kg: .* too large"),
    (lambda: avll.stable_intervals(M, "tg", kg=.5, kv=.5, search_range=(0, BIG)),
     "search_range: expected"),
    (lambda: avll.calibrate("first", RUNS, target=float("nan")), "target: .* got nan"),
])
def test_out_of_range_numbers_are_value_errors_naming_the_argument(call: Any, match: str
                                                                    ) -> None:
    with pytest.raises(ValueError, match=match):
        call()


def test_complex_input_is_refused_not_truncated() -> None:
    with pytest.raises(ValueError, match="command: .*complex values are not accepted"):
        avll.simulate(M, np.array([1 + 1j, 0]), 0.1)


@pytest.mark.parametrize("bad", [-1, 0.7, True, "speed", 4])
def test_upper_free_is_never_truncated(bad: Any) -> None:
    p = [[0.5, 0.1]]
    with pytest.raises(ValueError, match="upper_free: expected a gain name"):
        avll.batch_cost("first", p, RUNS, closed_loop=True, upper_free=[bad])
    # a name and its index are the same gain
    by_name = avll.batch_cost("first", p, RUNS, closed_loop=True, upper_free=["kg"])
    by_index = avll.batch_cost("first", p, RUNS, closed_loop=True, upper_free=[0])
    assert np.array_equal(by_name, by_index)


@pytest.mark.parametrize("kw", [{"init": None}, {"init": "cold"}, {"command_kind": None},
                                {"command_kind": "foo"}])
def test_string_options_are_named(kw: dict[str, Any]) -> None:
    (name,) = kw
    with pytest.raises(ValueError, match=f"^{name}: must be "):
        avll.simulate(M, [0.0, 1.0], 0.1, **kw)
    with pytest.raises(ValueError, match=f"^{name}: must be "):
        avll.simulate_full(M, [0.0, 1.0], 0.1, **kw)
    if name == "init":
        with pytest.raises(ValueError, match="^init: must be "):
            avll.batch_cost("first", [[0.5]], RUNS, **kw)


def test_exo_must_be_a_mapping() -> None:
    with pytest.raises(TypeError, match="exo: expected a mapping"):
        avll.simulate(avll.WithEffects(M, (avll.Grade(),)), [0.0, 1.0], 0.1, exo=5)  # type: ignore[arg-type]


@pytest.mark.parametrize(("kw", "match"), [
    ({"upper": (1, 2, 3, 4)}, "upper must be an avll.UpperLevel or None"),
    ({"exo": 5}, "exo must be a mapping"),
    ({"meta": 5}, "meta must be a mapping"),
])
def test_run_checks_its_optional_fields(kw: dict[str, Any], match: str) -> None:
    with pytest.raises(avll.DataError, match=f"run 'x': {match}"):
        avll.Run("x", [0, .1, .2], a=[0, 0, 0], **kw)


def test_stability_helpers_name_their_arguments() -> None:
    with pytest.raises(ValueError, match=r"kg, tg, kv: lengths do not broadcast \(2, 3, 1"):
        avll.exact_delay_codes(M, [.5, 1], [1.5, 1, 2], [.5])
    with pytest.raises(ValueError, match="^kg: expected an array of numbers"):
        avll.exact_delay_codes(M, "a", [1.5], [.5])
    with pytest.raises(TypeError, match="exact_delay_codes.* 'orders'"):
        avll.exact_delay_codes(M, .5, 1.5, .5, orders=[2])  # type: ignore[call-arg]
    with pytest.raises(ValueError, match="orders: at least one Padé order"):
        avll.pade_error_map(M, [.5], [1.5], [.5], orders=[])
    with pytest.raises(TypeError, match="^kg: must be a number"):
        avll.stable_intervals(M, "tg", kg=[.5], kv=.5)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="^level: must be"):
        avll.stable_intervals(M, "tg", kg=.5, kv=.5, level=[])  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="^axis: must be"):
        avll.stable_intervals(M, [], kg=.5, kv=.5)  # type: ignore[arg-type]


def _csv(tmp_path: Path, name: str, lines: list[str]) -> Path:
    p = tmp_path / name
    p.write_text("\n".join(lines) + "\n")
    return p


ROWS = ["run,t,a,command"] + [f"1,{i * 0.1:.1f},0,0" for i in range(30)]


def test_csv_errors_give_the_physical_line_past_blank_lines(tmp_path: Path) -> None:
    lines = ROWS[:5] + ["", "   ", ""] + ROWS[5:]
    bad = lines[:]
    bad[13] = bad[13].replace(",0,0", ",abc,0")  # physical line 14
    with pytest.raises(avll.DataError, match="column 'a' line 14: 'abc' is not a number"):
        load_canonical(_csv(tmp_path, "a.csv", bad), command_kind="acceleration")
    back = lines[:]
    back[10] = "1,0.2,0,0"  # physical line 11
    with pytest.raises(avll.DataError, match="column 't' line 11: time goes backwards"):
        load_canonical(_csv(tmp_path, "b.csv", back), command_kind="acceleration")
    huge = lines[:]
    huge[12] = huge[12].replace(",0,0", ",1e5,0")  # physical line 13
    with pytest.raises(avll.DataError, match=r"column 'a', row \d+ \(line 13\): acceleration"):
        load_canonical(_csv(tmp_path, "c.csv", huge), command_kind="acceleration")
    runs = load_canonical(_csv(tmp_path, "d.csv", lines), command_kind="acceleration")
    assert runs[0].meta["first_line"] == 2 and len(runs[0]) == 30


def test_csv_line_is_given_whatever_the_suffix(tmp_path: Path) -> None:
    huge = ROWS[:]
    huge[3] = huge[3].replace(",0,0", ",1e5,0")
    with pytest.raises(avll.DataError, match=r"huge.txt, column 'a', row 2 \(line 4\)"):
        load_canonical(_csv(tmp_path, "huge.txt", huge), command_kind="acceleration")


@pytest.mark.parametrize("digits", [400, 5000])
def test_sidecar_with_a_huge_integer_is_a_data_error(tmp_path: Path, digits: int) -> None:
    p = _csv(tmp_path, "s.csv", ROWS)
    big = "1" + "0" * digits
    Path(str(p) + ".meta.json").write_text(
        '{"command_kind": "acceleration", "runs": {"1": {"upper": {"kg": 0.5, "Tg": '
        + big + "}}}}")
    with pytest.raises(avll.DataError, match=r"s\.csv\.meta\.json: "):
        load_canonical(p)
