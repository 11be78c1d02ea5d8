"""Thread and memory guards: a request the machine cannot serve is refused at once
with a ValueError/TypeError naming the argument, before any thread is started or
any memory is allocated; the process stays alive."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

import avll
from avll import _core, _limits
from avll import reproduce as R
from avll.cli import main

M = avll.PAPER_TABLE_II["proposed"]
UP = avll.UpperLevel(kg=0.2, kv=0.5, Tg=2.0)
T = np.arange(200) * 0.05
LX, LV = 100.0 + 10.0 * T, np.full(T.size, 10.0)


def _os_threads() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("Threads:"):
            return int(line.split()[1])
    return -1  # pragma: no cover - not Linux


@pytest.fixture(scope="module")
def runs() -> list[avll.Run]:
    return avll.synth.paper_experiment(runs=(1, 3), duration=20.0)


def _thread_calls(runs: list[avll.Run]) -> dict[str, object]:
    return {
        "stability_map": lambda t: avll.stability_map(M, [0.1], [2.0], [0.1], threads=t),
        "stability_points": lambda t: avll.stability_points(M, 0.1, 2.0, 0.1, threads=t),
        "kv_threshold": lambda t: avll.kv_threshold(M, [0.1], [3.0], 0.1, 2.0, threads=t),
        "batch_cost": lambda t: avll.batch_cost("first", [[1.0]], runs, threads=t),
        "batch_cost with effects": lambda t: avll.batch_cost("first", [[1.0, 0.1]], runs,
                                                        effects=["delay"], threads=t),
        "calibrate": lambda t: avll.calibrate("first", runs, threads=t, max_generations=2),
        "calibrate_many": lambda t: avll.calibrate_many("first", runs, threads=t,
                                                        max_generations=2),
        "bootstrap": lambda t: avll.bootstrap("first", runs, n=2, threads=t,
                                              max_generations=2),
        "paper_workflow": lambda t: avll.paper_workflow(runs, cal_runs=None, models=("first",),
                                                        threads=t, max_generations=2),
        "reproduce": lambda t: R.reproduce("/nonexistent/never", threads=t, progress=False),
    }


CALLS = ["stability_map", "stability_points", "kv_threshold", "batch_cost",
         "batch_cost with effects", "calibrate", "calibrate_many", "bootstrap", "paper_workflow",
         "reproduce"]


@pytest.mark.parametrize("name", CALLS)
def test_a_million_threads_is_refused_at_once(name: str, runs: list[avll.Run]) -> None:
    call = _thread_calls(runs)[name]
    before = _os_threads()
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match=r"threads: 1000000 is more than 4 x the \d+ available"):
        call(10**6)  # type: ignore[operator]
    assert time.perf_counter() - t0 < 2.0
    assert _os_threads() <= before  # no thread was started
    assert not Path("/nonexistent/never").exists()


@pytest.mark.parametrize("name", CALLS)
@pytest.mark.parametrize("bad", [1.5, True, "2", None])
def test_non_integer_threads_are_type_errors(name: str, bad: object,
                                             runs: list[avll.Run]) -> None:
    with pytest.raises(TypeError, match="threads: must be an integer"):
        _thread_calls(runs)[name](bad)  # type: ignore[operator]


@pytest.mark.parametrize("name", CALLS)
def test_negative_threads(name: str, runs: list[avll.Run]) -> None:
    with pytest.raises(ValueError, match="threads: must be >= 0"):
        _thread_calls(runs)[name](-1)  # type: ignore[operator]


def test_the_bound_is_four_per_core_and_allowed_values_work(runs: list[avll.Run]) -> None:
    assert _core.max_threads() == _core.THREADS_PER_CORE * _core.available_cores()
    assert _core.THREADS_PER_CORE == 4
    top = _core.max_threads()
    assert _limits.check_threads(np.int64(top)) == top
    a = avll.batch_cost("first", [[1.0], [2.0]], runs, threads=0)
    b = avll.batch_cost("first", [[1.0], [2.0]], runs, threads=top)
    np.testing.assert_array_equal(a, b)


def test_rust_side_refuses_too_many_threads_itself(runs: list[avll.Run]) -> None:
    """The bound is enforced in rust/parallel.rs too (a caller of avll._core)."""
    too_many = _core.max_threads() + 1
    with pytest.raises(ValueError, match="threads"):
        _core.stability_map("second", [0.7, 0.04, 0.13, 0.78], np.array([0.1]),
                            np.array([2.0]), np.array([0.1]), 2, too_many)
    kw = avll.RunSet(runs).cost_kw()
    with pytest.raises(ValueError, match="threads"):
        _core.batch_cost("first", np.ones((1, 1)), threads=too_many, **kw)


def test_cli_threads_one_line_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["stability-map", "--threads", "1000000", "--out", "unused.png"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "threads: 1000000" in err and "Traceback" not in err
    assert not Path("unused.png").exists()


# ------------------------------------------------------------------ memory


def test_platoon_of_a_billion_followers_is_refused() -> None:
    with pytest.raises(ValueError, match=r"platoon: followers=1000000000 .* needs about "
                                         r"[\d.]+ TB but only .* followers per call fit"):
        avll.platoon(M, LX, LV, 0.05, UP, followers=10**9)
    # the process is alive and a normal platoon still works
    tr = avll.platoon(M, LX, LV, 0.05, UP, followers=3)
    assert tr.a.shape == (3, T.size)


@pytest.mark.parametrize("bad", [1.7, True, "3", None])
def test_followers_must_be_an_integer(bad: object) -> None:
    with pytest.raises(TypeError, match="followers: must be an integer"):
        avll.platoon(M, LX, LV, 0.05, UP, followers=bad)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="followers: must be >= 1"):
        avll.platoon(M, LX, LV, 0.05, UP, followers=0)


def test_too_large_stability_map_is_refused() -> None:
    kg = np.linspace(0.01, 1, 100_000)
    tg = np.linspace(0, 15, 100_000)
    kv = np.linspace(0, 1, 1000)  # 1e13 points
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match=r"stability_map: 100000 kg x 100000 tg x 1000 kv.*"
                                         r"needs about .* TB.*split the grid"):
        avll.stability_map(M, kg, tg, kv)
    assert time.perf_counter() - t0 < 2.0
    with pytest.raises(ValueError, match="stability_points"):
        avll.stability_points(M, np.zeros((1, 1, 1)),
                              np.broadcast_to(np.float64(2.0), (10**6, 10**6)), 0.1)


def test_stability_points_names_the_argument_that_is_not_numbers() -> None:
    """A non-numeric coordinate is named as such, not reported as a broadcasting
    failure; coordinates that really do not broadcast still say so."""
    for i, name in enumerate(("kg", "tg", "kv")):
        args: list[object] = [0.5, 1.0, 0.5]
        args[i] = "x"
        with pytest.raises(ValueError, match=f"^{name}: expected an array of numbers") as e:
            avll.stability_points(M, *args)
        assert "broadcast" not in str(e.value)
    with pytest.raises(ValueError, match="kg, tg, kv: shapes do not broadcast"):
        avll.stability_points(M, np.zeros(3), np.zeros(4), 0.1)


def test_batch_cost_and_bootstrap_are_estimated(monkeypatch: pytest.MonkeyPatch,
                                                runs: list[avll.Run]) -> None:
    """On a machine with 50 MB free, a (P, R) cost matrix of 80 MB is refused (the
    estimate P x R x 8 bytes), as is a bootstrap whose resamples cannot fit."""
    monkeypatch.setattr(_limits, "available_memory", lambda: (50_000_000, "a test limit"))
    rs = runs * 500  # 1000 runs
    with pytest.raises(ValueError, match=r"batch_cost: 10000 parameter rows x 1000 runs x 8 "
                                         r"bytes: needs about 80.0 MB .*a test limit.*slices"):
        avll.batch_cost("first", np.ones((10_000, 1)), rs)
    with pytest.raises(ValueError, match="bootstrap: n=1000000 resamples"):
        avll.bootstrap("first", rs, n=10**6)
    with pytest.raises(ValueError, match=r"calibrate: 100000 problem\(s\)"):
        avll.calibrate_many("first", runs, [[0]] * 100_000, starts=1)


def test_check_memory_message_and_small_calls(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(_limits, "available_memory", lambda: (1_000_000_000, "x"))
    _limits.check_memory(10.0, "tiny", "never")  # below SMALL: not even looked at
    _limits.check_memory(0.5e9, "fits", "never")
    with pytest.raises(ValueError, match=r"big: needs about 900.0 MB but only 1.0 GB can be "
                                         r"allocated \(x\); chunk it \(at most 800 rows"):
        _limits.check_memory(0.9e9, "big", "chunk it", per=1e6, unit="rows")
    with pytest.raises(ValueError, match="more than any machine"):
        _limits.check_memory(float("inf"), "huge", "no")


def test_available_memory_is_sane() -> None:
    avail, source = _limits.available_memory()
    assert avail is not None and avail > 0 and source


_RLIMIT_CHILD = textwrap.dedent("""
    import resource, sys
    import numpy as np
    import avll
    from avll import _limits
    vm = _limits._status_kb("VmSize")
    limit = vm + 1_500_000_000  # 1.5 GB of address space left
    resource.setrlimit(resource.RLIMIT_AS, (limit, resource.RLIM_INFINITY))
    avail, source = _limits.available_memory()
    assert "RLIMIT_AS" in source, source
    m = avll.PAPER_TABLE_II["second"]
    t = np.arange(2000) * 0.05
    lx, lv = 100.0 + 10.0 * t, np.full(t.size, 10.0)
    up = avll.UpperLevel(kg=0.2, kv=0.5, Tg=2.0)
    try:  # 2 x 4 x 8 x 2000 x 40000 = 5.1 GB
        avll.platoon(m, lx, lv, 0.05, up, followers=40_000)
        print("platoon: no error")
    except ValueError as e:
        print("platoon refused:", "RLIMIT_AS" in str(e))
    try:  # 2 x 1.6e9 bytes
        avll.stability_map(m, np.linspace(0.01, 1, 4000), np.linspace(0, 15, 4000),
                           np.linspace(0, 1, 100))
        print("map: no error")
    except ValueError as e:
        print("map refused:", "RLIMIT_AS" in str(e))
    small = avll.platoon(m, lx, lv, 0.05, up, followers=50)  # 6.4 MB: fine
    print("alive", small.a.shape)
""")


@pytest.mark.skipif(sys.platform != "linux", reason="RLIMIT_AS and /proc are Linux")
def test_lowered_rlimit_as_refuses_instead_of_aborting() -> None:
    """Under an address-space limit the Rust allocation would abort the process
    (exit 134); the estimate sees the limit and refuses with a ValueError instead."""
    res = subprocess.run([sys.executable, "-c", _RLIMIT_CHILD], capture_output=True,
                         text=True, timeout=120, env={**os.environ, "RAYON_NUM_THREADS": "2"})
    assert res.returncode == 0, res.stderr
    assert "platoon refused: True" in res.stdout
    assert "map refused: True" in res.stdout
    assert "alive (50, 2000)" in res.stdout


def test_the_platoon_hint_is_exact() -> None:
    """The refusal's advice -- simulate the platoon in slices, the last follower of a
    slice leading the next -- gives the same trajectories bit for bit."""
    rng = np.random.default_rng(0)
    acc = np.convolve(rng.normal(scale=0.6, size=2000), np.ones(20) / 20, mode="same")
    lv = np.maximum(15 + np.cumsum(acc) * 0.05, 0.0)
    lx = 40.0 + np.concatenate([[0.0], np.cumsum((lv[1:] + lv[:-1]) / 2) * 0.05])
    up = avll.UpperLevel(0.5, 0.2, 2.0, 9.5)
    full = avll.platoon(M, lx, lv, 0.05, up, 4)
    first = avll.platoon(M, lx, lv, 0.05, up, 2)
    second = avll.platoon(M, first.x[-1], first.v[-1], 0.05, up, 2)
    for key in ("a", "v", "x", "command"):
        np.testing.assert_array_equal(getattr(full, key)[2:], getattr(second, key))
