"""No request aborts the process: every allocation that grows
with a request is estimated before it is made (boundary, exact delay, chunked and
distributed maps, the distributed bootstrap) or made fallibly in Rust, so a request
the machine cannot serve is a ValueError with the estimate. The requests that aborted
the process (SIGABRT from Rust) run in a child process under an address-space limit,
so a regression fails the test instead of killing the test runner."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import avll
from avll import _core, _limits
from avll import maps as avll_maps
from avll import stability as S

M = avll.PAPER_TABLE_II["second"]
LIMIT = 3 * 2**30  # RLIMIT_AS of the child: 3 GiB

_PRELUDE = f"""
import resource
resource.setrlimit(resource.RLIMIT_AS, ({LIMIT}, {LIMIT}))
import numpy as np
import avll
from avll import _core, maps
m = avll.PAPER_TABLE_II["second"]
big = np.linspace(0.1, 1.0, 100_000)
"""

#: name -> a call that aborted the process (or would, with the Python estimate gone)
ABORTING = {
    # three boundary requests of the audit: a large grid, a long scan, a huge scan
    "boundary_grid": "avll.boundary(m, 'tg_min', kg=big, kv=big)",
    "boundary_scan": "avll.boundary(m, 'tg_min', kg=[0.5], kv=[0.5], n_scan=10**10)",
    "boundary_scan_huge": "avll.boundary(m, 'tg_min', kg=[0.5], kv=[0.5], n_scan=2**62)",
    "stable_intervals_scan": "avll.stable_intervals(m, 'tg', kg=0.5, kv=0.5, n_scan=10**10)",
    "min_stable_tg_scan": "avll.min_stable_tg(m, n_scan=10**10)",
    "kv_supremum_grid": "avll.kv_supremum(m, n_grid=10**9)",
    # the Rust bindings themselves (no Python estimate in front): fallible allocation
    "rust_boundary": ("_core.stability_boundary('second', list(m.to_array()), 1, big, big, "
                      "0.0, 15.0, 'inf')"),
    "rust_map": ("_core.stability_map('second', list(m.to_array()), np.linspace(0.1, 1, 3000), "
                 "np.linspace(0, 15, 3000), np.linspace(0, 1, 3000), 2, 1)"),
    "rust_delay_margin_nw": ("_core.delay_margin('second', list(m.to_array()), np.ones(1), "
                             "np.ones(1), np.ones(1), 0.01, 60.0, 10**10)"),
    # a large map_dataset chunk: refused when the map is built, and by the block itself
    "map_dataset_chunk": ("avll.map_dataset(m, np.linspace(0.1, 1, 3000), np.linspace(0, 15, "
                          "3000), np.linspace(0, 1, 3000), chunks={'kg': 3000, 'Tg': 3000})"),
    "map_dataset_block": (
        "maps._map_block('second', list(m.to_array()), np.linspace(0.1, 1, 3000), "
        "np.linspace(0, 15, 3000), np.linspace(0, 1, 3000), 2, 1, 100, "
        "block_info={None: {'array-location': [(0, 3000), (0, 3000), (0, 3000)]}})"),
    "map_dataset_exact_eager": ("avll.map_dataset(m, np.linspace(0.1, 1, 1000), "
                                "np.linspace(0, 15, 1000), np.linspace(0, 1, 1000), None)"),
    # numpy allocations that ended in MemoryError (no estimate)
    "pade_error_map": ("avll.pade_error_map(m, np.linspace(0.1, 1, 1000), np.linspace(0, 15, "
                       "1000), np.linspace(0, 1, 200))"),
    "stability_probability": ("avll.stability_probability([m] * 50, np.linspace(0.1, 1, 1000), "
                              "np.linspace(0, 15, 1000), np.linspace(0, 1, 50))"),
    # distributed work: refused before any cluster is contacted (no server at port 9)
    "sweep": ("avll.sweep([m], np.linspace(0.1, 1, 3000), np.linspace(0, 15, 3000), "
              "np.linspace(0, 1, 3000), client='tcp://127.0.0.1:9')"),
    "sweep_gathered": ("avll.sweep([m] * 20, np.linspace(0.1, 1, 1000), np.linspace(0, 15, "
                       "1000), np.linspace(0, 1, 200), client='tcp://127.0.0.1:9')"),
    "bootstrap_distributed_n": ("maps.bootstrap_distributed('first', [1], n=10**12, "
                                "client='tcp://127.0.0.1:9')"),
    "bootstrap_distributed_ga": (
        "maps.bootstrap_distributed('first', avll.synth.paper_experiment(runs=(1,), "
        "duration=20.0), n=3, client='tcp://127.0.0.1:9', pop_size=1_000_000, "
        "max_generations=10**9)"),
}


def _child(call: str) -> subprocess.CompletedProcess[str]:
    code = _PRELUDE + textwrap.dedent(f"""
    try:
        {call}
    except ValueError as e:
        print("REFUSED:", e)
    else:
        print("NO ERROR")
    """)
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300, env={**os.environ, "RAYON_NUM_THREADS": "2"})


@pytest.mark.skipif(sys.platform != "linux", reason="RLIMIT_AS is a Linux limit here")
@pytest.mark.parametrize("name", sorted(ABORTING))
def test_request_is_refused_not_aborted(name: str) -> None:
    res = _child(ABORTING[name])
    assert res.returncode == 0, f"exit {res.returncode}:\n{res.stderr[-2000:]}"
    assert "REFUSED:" in res.stdout, res.stdout + res.stderr
    msg = res.stdout.split("REFUSED:", 1)[1]
    # the refusal states the estimate, or the stated limit of the argument
    assert re.search(r"needs? about|must be <=|must be in 2\.\.=", msg), msg


def test_refusals_name_the_estimate_and_the_remedy(monkeypatch: pytest.MonkeyPatch) -> None:
    # 80 % of 50 MB may be planned: every request below needs more (none is computed)
    monkeypatch.setattr(_limits, "available_memory", lambda: (50_000_000, "a test limit"))
    kg = np.linspace(0.1, 1, 3000)
    with pytest.raises(ValueError, match=r"boundary: 3000 kg x 3000 kv.*needs about 72\.\d MB"
                                         r".*a test limit.*split the grid"):
        avll.boundary(M, "tg_min", kg=kg, kv=kg)
    with pytest.raises(ValueError, match=r"a chunk of 3000 kg x 3000 Tg x 20 kv.*needs about "
                                         r"180\.0 MB.*smaller chunks"):
        avll.map_dataset(M, kg, kg, np.linspace(0, 1, 20), chunks={"kg": 3000, "Tg": 3000})
    with pytest.raises(ValueError, match=r"exact_delay_codes: 5000000 points.*130\.0 MB"):
        avll.exact_delay_codes(M, np.full(5_000_000, 0.5), 2.0, 0.5)
    with pytest.raises(ValueError, match=r"sweep: one map .*needs about"):
        avll.sweep([M], kg, kg, np.linspace(0, 1, 20), client="tcp://127.0.0.1:9")
    # fits: not refused (small requests are not even checked)
    assert avll.boundary(M, "tg_min", kg=[0.5], kv=[0.5]).shape == (1, 1)


def test_scan_limits_are_the_engines() -> None:
    assert S.MAX_SCAN == _core.MAX_SCAN and S.MAX_GRID == _core.MAX_GRID
    with pytest.raises(ValueError, match=f"n_scan: must be <= {S.MAX_SCAN}"):
        avll.boundary(M, "tg_min", kg=[0.5], kv=[0.5], n_scan=S.MAX_SCAN + 1)
    with pytest.raises(ValueError, match=f"n_scan: must be in 2..={S.MAX_SCAN}"):
        _core.stability_intervals("second", list(M.to_array()), 1, [0.5, 0.0, 0.5], 0.0,
                                  15.0, n_scan=S.MAX_SCAN + 1)
    with pytest.raises(ValueError, match=f"n_grid: must be in 2..={S.MAX_GRID}"):
        _core.stability_extremum("second", list(M.to_array()), "tg_min", (1e-3, 2.0, True),
                                 (0.0, 1.2, False), (0.0, 15.0, False), n_grid=S.MAX_GRID + 1)


# ------------------------------------------------------------ integers, keywords


@pytest.mark.parametrize("kw", [{"n": 2.5}, {"n": True}, {"batch": 1.5}, {"seed": 0.5},
                                {"threads": 1.0}])
def test_bootstrap_distributed_refuses_non_integers(kw: dict[str, object]) -> None:
    runs = avll.synth.paper_experiment(runs=(1,), duration=10.0)
    args: dict[str, object] = {"n": 3, **kw}
    with pytest.raises(TypeError, match=f"{next(iter(kw))}: must be an integer"):
        avll_maps.bootstrap_distributed("first", runs, client="tcp://127.0.0.1:9", **args)


def test_distributed_calibration_refuses_unknown_keywords_before_any_cluster() -> None:
    runs = avll.synth.paper_experiment(runs=(1,), duration=10.0)
    with pytest.raises(ValueError, match="max_generatons: unknown GA option"):
        avll.calibrate_many_distributed("first", runs, client="tcp://127.0.0.1:9",
                                        max_generatons=3)
    with pytest.raises(ValueError, match="max_generatons: unknown GA option"):
        avll_maps.bootstrap_distributed("first", runs, n=3, client="tcp://127.0.0.1:9",
                                        max_generatons=3)


def test_exact_delay_codes_refuses_unknown_keywords() -> None:
    with pytest.raises(TypeError, match="unexpected keyword argument 'budgett'"):
        avll.exact_delay_codes(M, 0.5, 2.0, 0.5, budgett=10)  # type: ignore[call-arg]
    with pytest.raises(TypeError, match="unexpected keyword argument 'budgett'"):
        avll.pade_report(M, [0.5], [2.0], [0.5], budgett=10)
    with pytest.raises(TypeError, match="budget: must be an integer"):
        avll.exact_delay_codes(M, 0.5, 2.0, 0.5, budget=2.5)
    codes, ok = avll.exact_delay_codes(M, 0.5, 2.0, 0.5, budget=10)
    assert codes.shape == ok.shape == (1,)


@pytest.mark.parametrize("call", [
    lambda: avll.boundary(M, "tg_min", kg=[0.5], kv=[0.5], n_scan=256.5),
    lambda: avll.boundary(M, "tg_min", kg=[0.5], kv=[0.5], threads=1.5),
    lambda: avll.stable_intervals(M, "tg", kg=0.5, kv=0.5, n_scan=100.0),
    lambda: avll.min_stable_tg(M, n_grid=32.5),
    lambda: avll.kv_supremum(M, n_scan=True),
    lambda: avll.map_dataset(M, [0.5], [2.0], [0.5], threads=1.5),
    lambda: avll.map_dataset(M, [0.5], [2.0], [0.5], None, budget=100.5),
    lambda: avll.sweep([M], [0.5], [2.0], [0.5], threads=2.5, client="tcp://127.0.0.1:9"),
])
def test_integer_arguments_refuse_non_integers(call: object) -> None:
    with pytest.raises(TypeError, match="must be an integer"):
        call()  # type: ignore[operator]


@pytest.mark.skipif(sys.platform != "linux", reason="RLIMIT_AS is a Linux limit here")
def test_cli_stability_map_scheduler_refuses_with_the_estimate(tmp_path: object) -> None:
    """``stability-map --scheduler`` went to the cluster without an estimate: now the
    command refuses before any scheduler is contacted (none listens at port 9)."""
    import resource
    from pathlib import Path

    out = Path(str(tmp_path)) / "m.png"

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (LIMIT, LIMIT))

    res = subprocess.run(
        [sys.executable, "-m", "avll", "stability-map", "--models", "second", "--kg", "0.01",
         "1", "3000", "--tg", "0", "15", "3000", "--kv", "0", "1", "3000", "--scheduler",
         "tcp://127.0.0.1:9", "--out", str(out)],
        capture_output=True, text=True, timeout=300, preexec_fn=limit,
        env={**os.environ, "RAYON_NUM_THREADS": "2"})
    assert res.returncode == 2, res.stderr[-2000:]
    assert "Traceback" not in res.stderr
    # the maps come back to this process: the whole grid is checked before the sweep
    assert re.search(r"--kg x --tg x --kv: 3000 x 3000 x 3000 = 27000000000 points x 1 "
                     r"map\(s\): needs about 54\.0 GB", res.stderr), res.stderr
    assert not out.exists()
