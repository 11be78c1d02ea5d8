"""``avll study openacc`` on any campaign: runs of any length (no
interval, with the reason, instead of a crash), the setting order in each campaign's
own order (``setting_rank``), ACC state known / human / unknown (``--acc-unknown``),
the run meta in the JSON, and the output folder committed as a whole with its
manifest. Runs are built in memory (the study reads any run's ``meta``, with
fallbacks); the GA budget is tiny (these tests check the bookkeeping, not the fits)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from loader_helpers import native_platoon

from avll import _atomic
from avll.data import Run
from avll.studies import openacc as st

FAST = {"model": "first", "models": ("first",), "max_generations": 3, "pop_size": 8,
        "starts": 1, "n_boot": 100, "intervals": False, "structures": False}


def platoon_runs(stem, *, n=1200, tg=1.5, seed=0, meta=None, vehicles=4, dt=0.1):
    """One closed-loop run per follower of a synthetic platoon, with ``meta``."""
    p = native_platoon(n=n, vehicles=vehicles, tg=tg, seed=seed, dt=dt)
    out = []
    for i in range(2, vehicles + 1):
        v, lv = p[f"Speed{i}"], p[f"Speed{i - 1}"]
        x = p[f"s{i}"] - p[f"s{i}"][0]
        lead_x = x + (p[f"s{i - 1}"] - p[f"s{i}"] - 4.5)
        m = {"file": f"/data/{stem}.csv", "car": f"CAR{i}", "vehicle_index": i,
             "lead_index": i - 1, "position": i - 1, **(meta or {})}
        out.append(Run(run_id=f"{stem}/v{i - 1}-v{i}", t=p["t"] - p["t"][0],
                       a=p[f"a{i}"], v=v, x=x, lead_x=lead_x, lead_v=lv, meta=m))
    return out


def test_measured_amplification_any_length():
    dt = 0.1
    rng = np.random.default_rng(1)
    for seconds, has_amp, has_ci in ((3.0, False, False), (22.0, False, False),
                                     (58.0, False, False), (62.0, True, False),
                                     (300.0, True, True)):
        t = np.arange(0, seconds, dt)
        lead = 10 + 0.5 * np.sin(2 * np.pi * 0.05 * t) + 0.01 * rng.standard_normal(t.size)
        v = 10 + 0.6 * np.sin(2 * np.pi * 0.05 * (t - 1.0))
        d = st.measured_amplification(v, lead, dt, n_boot=200)
        assert (d["amplification"] is not None) == has_amp, seconds
        assert (d["ci"][0] is not None) == has_ci, seconds
        if not has_amp:
            assert "too short" in d["amplification_reason"]
        if not has_ci:
            assert d["ci"] == [None, None] and d["ci_reason"]
        else:
            assert d["ci"][0] < d["amplification"] < d["ci"][1]
            assert d["amplification"] == pytest.approx(1.2, rel=0.05)
    # a predecessor at constant speed does not excite
    t = np.arange(0, 300, dt)
    d = st.measured_amplification(10 + 0 * t, 10 + 0.001 * np.sin(t), dt)
    assert d["amplification"] is None and "does not excite" in d["amplification_reason"]


def test_setting_order_uses_each_campaigns_own_order():
    rows = [
        # campaign A ranks min < second shortest < L; SL resolved to the long rank
        {"campaign": "A", "car": "X", "setting": "min", "setting_rank": 0, "Tg": 1.0},
        {"campaign": "A", "car": "X", "setting": "second shortest", "setting_rank": 1,
         "Tg": 1.5},
        {"campaign": "A", "car": "X", "setting": "L", "setting_rank": 2, "Tg": 1.4},
        {"campaign": "A", "car": "X", "setting": "SL", "setting_rank": 2, "Tg": 2.2},
        # campaign B: the same car model; its settings are never compared with A's
        {"campaign": "B", "car": "X", "setting": "S", "setting_rank": 0, "Tg": 3.0},
        {"campaign": "B", "car": "X", "setting": "L", "setting_rank": 1, "Tg": 2.5},
        # a setting without an order is ignored
        {"campaign": "B", "car": "X", "setting": "??", "setting_rank": None, "Tg": 9.0},
    ]
    o = st.setting_order(rows)
    assert o["checked"] == 4
    got = {(c["campaign"], c["longer"], c["shorter"]): c["held"] for c in o["checks"]}
    assert got == {("A", "L/SL", "second shortest"): True,  # median(1.4, 2.2) = 1.8 > 1.5
                   ("A", "L/SL", "min"): True, ("A", "second shortest", "min"): True,
                   ("B", "L", "S"): False}
    assert o["held"] == 3
    per = {(p["campaign"], p["car"]): (p["held"], p["checked"]) for p in o["per_car"]}
    assert per == {("A", "X"): (3, 3), ("B", "X"): (0, 1)}
    # the same rows without campaigns would compare A's and B's settings: here they differ
    flat = st.setting_order([{k: v for k, v in r.items() if k != "campaign"} for r in rows])
    assert flat["checked"] == 3


def test_run_meta_contract_and_fallbacks():
    r = platoon_runs("f", n=300, meta={"setting": "min", "setting_rank": 0, "acc": True,
                                        "campaign": "Casale"})[0]
    m = st.run_meta(r)
    assert (m["setting"], m["setting_rank"], m["acc"], m["campaign"]) == ("min", 0, True,
                                                                          "Casale")
    # an older loader: setting_in_file raw, no rank: L > M > S
    old = platoon_runs("g", n=300, meta={"setting": None, "setting_in_file": "M",
                                          "acc": False})[0]
    m = st.run_meta(old, root="/somewhere/Zala")
    assert (m["setting"], m["setting_rank"], m["acc"], m["campaign"]) == ("M", 1, False,
                                                                          "Zala")
    # a canonical run: nothing known
    bare = Run(run_id="r1", t=np.arange(3.0), a=np.zeros(3))
    m = st.run_meta(bare)
    assert (m["file"], m["car"], m["setting"], m["setting_rank"], m["acc"]) == (
        "r1", "r1", None, None, None)


@pytest.fixture(scope="module")
def mixed_runs():
    """Two campaigns; ACC, human and unknown runs; one 22 s run."""
    a = {"campaign": "A", "acc": True}
    runs = (platoon_runs("A_long", meta={**a, "setting": "L", "setting_rank": 2})
            + platoon_runs("A_short", tg=0.8, seed=1,
                           meta={**a, "setting": "shortest", "setting_rank": 0})
            + platoon_runs("A_human", seed=2, meta={"campaign": "A", "acc": False,
                                                     "setting": "", "setting_rank": None})
            + platoon_runs("B_unknown", seed=3, meta={"campaign": "B", "acc": None,
                                                       "setting": "min", "setting_rank": 0})
            + platoon_runs("B_tiny", n=225, seed=4, meta={"campaign": "B", "acc": True,
                                                          "setting": "L", "setting_rank": 1}))
    return runs


def test_acc_unknown_exclude_and_include(mixed_runs):
    res = st.openacc_study(mixed_runs, figures=True, **FAST)
    s = res.summary
    assert s["acc_unknown"] == "exclude" and s["campaigns"] == ["A", "B"]
    assert len(s["cars"]) == 12 and len(s["left_out"]) == 3
    assert all("unknown" in e["reason"] and e["car"] for e in s["left_out"])
    for c in s["cars"]:
        assert {"setting", "setting_rank", "acc", "campaign", "group"} <= set(c)
        assert c["group"] == ("human" if c["acc"] is False else "acc")
        assert c["acc"] is not None
    # human runs are a control: never in the ACC comparisons nor the setting order
    comp = s["model_comparison"]["first"]
    n_acc = sum(c["group"] == "acc" and c["amplification_measured"] is not None
                for c in s["cars"])
    assert comp["amplification_replay_acc"]["n"] <= n_acc
    assert comp["string_stability"]["cars_acc"] == 9
    so = s["setting_order"]
    assert so["checked"] == 3 and set(so["campaigns"]) == {"A"}
    assert all(c["campaign"] == "A" and c["longer"] == "L" and c["shorter"] == "shortest"
               for c in so["checks"])
    # the 22 s run: no amplification, no interval, each with its reason; no crash
    tiny = [c for c in s["cars"] if c["file"].endswith("B_tiny.csv")]
    assert len(tiny) == 3
    for c in tiny:
        assert c["amplification_measured"] is None and "too short" in c[
            "amplification_measured_reason"]
        assert c["amplification_measured_ci"] == [None, None]
        assert c["amplification_predicted"] is None and c["amplification_predicted_reason"]
    ov = {(o["campaign"], o["car"]): o for o in s["car_overview"]}
    assert ov[("B", "CAR2")]["runs_left_out"] == 1 and ov[("B", "CAR2")]["runs_studied"] == 1
    assert ov[("A", "CAR3")]["acc"] == {"ACC": 2, "human": 1}
    assert "| B | CAR2 |" in res.report and "ACC state unknown" in res.report
    json.dumps(_atomic.json_safe(s), allow_nan=False)

    inc = st.openacc_study(mixed_runs, acc_unknown="include", figures=False, **FAST).summary
    assert len(inc["cars"]) == 15 and not inc["left_out"]
    unk = [c for c in inc["cars"] if c["acc"] is None]
    assert len(unk) == 3 and all(c["group"] == "acc" for c in unk)
    # campaign B now has min (0) and L (1) for each car: checked within B only
    assert set(inc["setting_order"]["campaigns"]) == {"A", "B"}
    assert inc["setting_order"]["campaigns"]["B"]["checked"] == 3
    with pytest.raises(ValueError, match="acc_unknown"):
        st.openacc_study(mixed_runs, acc_unknown="maybe", **FAST)


def test_only_unknown_runs_is_a_clear_error(mixed_runs):
    unk = [r for r in mixed_runs if r.meta["acc"] is None]
    with pytest.raises(ValueError, match="3 of unknown ACC state.*--acc-unknown include"):
        st.openacc_study(unk, **FAST)


def test_save_is_whole_with_manifest(mixed_runs, tmp_path, monkeypatch):
    res = st.openacc_study(mixed_runs[:3], figures=True, **FAST)
    out, js = tmp_path / "out", tmp_path / "s.json"
    res.save(out, js)
    man = _atomic.read_manifest(out)
    assert {"summary.json", "report.md", "cars.csv", "amplification.png"} <= set(man["files"])
    assert man["command"] == "avll study openacc"
    old = {p.name: p.read_bytes() for p in out.iterdir()}
    old_js = js.read_bytes()
    # Ctrl-C while the new outputs are being written: the old folder and JSON stay whole
    res2 = st.openacc_study(mixed_runs[3:6], figures=True, **FAST)
    calls = []

    def boom(self, *a, **k):
        calls.append(1)
        raise KeyboardInterrupt

    import matplotlib.figure
    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", boom)
    with pytest.raises(KeyboardInterrupt):
        res2.save(out, js)
    assert calls
    assert {p.name: p.read_bytes() for p in out.iterdir()} == old
    assert js.read_bytes() == old_js
    _atomic.read_manifest(out)
    monkeypatch.undo()
    res2.save(out, js)
    assert json.loads(js.read_text()) == json.loads((out / "summary.json").read_text())
    assert json.loads(js.read_text())["cars"][0]["run_id"] == mixed_runs[3].run_id
    _atomic.read_manifest(out)
    assert not [p for p in out.iterdir() if p.name.startswith(".")]


def test_figure_with_an_interval_that_excludes_the_estimate():
    """A percentile interval need not contain the estimate: no negative error bar."""
    from avll.plotting import amplification_per_car

    cars = [{"amplification_measured": 1.2, "amplification_measured_ci": [1.25, 1.4],
             "acc": True, "group": "acc",
             "models": {"first": {"amplification_H": 1.1, "amplification_replay": 1.15}}},
            {"amplification_measured": 0.9, "amplification_measured_ci": [None, None],
             "acc": None, "group": "acc",
             "models": {"first": {"amplification_H": None, "amplification_replay": 0.8}}}]
    fig = amplification_per_car(cars, ["first"])
    assert math.isfinite(fig.axes[0].get_xlim()[0])



def _campaign(name):
    from loader_helpers import DATA, NO_DATA

    d = DATA / name
    if not d.is_dir():
        pytest.skip(NO_DATA)
    return d


@pytest.mark.data
@pytest.mark.slow
def test_real_campaign_jrc_low_speed(tmp_path):
    """The whole study (tiny GA) on the JRC low-speed campaign folder as distributed:
    short stretches, two settings named in words, runs of unknown ACC state."""
    from avll.cli import main

    d = _campaign("openacc-jrc/JRC low speed")
    out, js = tmp_path / "o", tmp_path / "s.json"
    assert main(["study", "openacc", str(d), "--out", str(out), "--json", str(js),
                 "--max-generations", "3", "--pop-size", "8", "--starts", "1",
                 "--bootstrap", "100", "--model", "first", "--models", "first", "--resamples",
                 "20", "--structures", "none", "-q"]) == 0
    s = json.loads(js.read_text())
    _atomic.read_manifest(out)
    assert s["campaigns"] == ["JRC low speed"] and s["cars"]
    for c in s["cars"]:
        assert c["setting"] in ("shortest", "second shortest") and c["acc"] is True
        assert c["setting_rank"] == (0 if c["setting"] == "shortest" else 1)
        for k in ("amplification_measured", "amplification_measured_ci"):
            v = c[k][0] if k.endswith("_ci") else c[k]
            assert v is not None or c[f"{k}_reason"]
    # the loader's runs of unknown ACC state are left out and counted
    assert all("unknown" in e["reason"] for e in s["left_out"])
    assert sum(o["runs_left_out"] for o in s["car_overview"]) == (
        len(s["left_out"]) + len(s["dropped_by_loader"]))
    so = s["setting_order"]
    assert so["checked"] > 0 and all(c["longer"] == "second shortest" for c in so["checks"])
    assert "## Cars" in (out / "report.md").read_text()


@pytest.mark.data
@pytest.mark.slow
def test_real_mixed_folder(tmp_path):
    """Two campaigns in one folder (links to the files as distributed): each keeps its
    own settings; none is compared across campaigns."""
    mixed = tmp_path / "mixed"
    for name in ("openacc-jrc/Casale", "openacc-jrc/JRC low speed"):
        src = _campaign(name)
        dst = mixed / src.name
        dst.mkdir(parents=True)
        for f in src.iterdir():
            if f.is_file():
                (dst / f.name).symlink_to(f)
    res = st.openacc_study(mixed, figures=True, **FAST)
    s = res.summary
    assert s["campaigns"] == ["Casale", "JRC low speed"]
    by = {}
    for c in s["cars"]:
        by.setdefault(c["campaign"], set()).add(c["setting"])
    assert by["Casale"] == {"min"} and by["JRC low speed"] == {"shortest", "second shortest"}
    assert set(s["setting_order"]["campaigns"]) <= {"JRC low speed"}
    res.save(tmp_path / "o")
    _atomic.read_manifest(tmp_path / "o")


@pytest.mark.slow
@pytest.mark.parametrize("when", ["early", "staged"])
def test_ctrl_c_leaves_the_old_folder_or_the_new_one(when, tmp_path):
    """SIGINT to ``avll study openacc --out DIR --json J`` over an earlier result: early
    (loading or calibrating) or once the new outputs are being staged. Either way the
    folder verifies against its manifest and the JSON copy is the folder's summary."""
    import os
    import subprocess
    import sys
    import time
    from pathlib import Path

    from loader_helpers import write_native
    from signal_helpers import SIGINT_DEFAULT

    from avll.cli import main

    data = tmp_path / "camp"
    write_native(data / "a.csv", native_platoon(n=900), setting="L")
    write_native(data / "b.csv", native_platoon(n=900, tg=0.8, seed=1), setting="S")
    out, js = tmp_path / "out", tmp_path / "s.json"
    cli = ["study", "openacc", str(data), "--out", str(out), "--json", str(js),
           "--max-generations", "3", "--pop-size", "8", "--starts", "1", "--bootstrap", "100",
           "--model", "first", "--models", "first", "-q"]
    assert main([*cli, "--seed", "1"]) == 0
    import avll

    # the child imports the avll under test (an installed wheel or the source tree)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(Path(avll.__file__).resolve().parents[1]), os.environ.get("PYTHONPATH", "")]),
        "MPLBACKEND": "Agg"}
    p = subprocess.Popen([sys.executable, "-m", "avll", *cli, "--seed", "2"], env=env,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         **SIGINT_DEFAULT)
    if when == "early":
        time.sleep(1.0)
    else:
        deadline = time.monotonic() + 120
        while not any(q.name.startswith(_atomic.STAGING_PREFIX) for q in out.iterdir()):
            if p.poll() is not None or time.monotonic() > deadline:
                break
            time.sleep(0.002)
    if p.poll() is None:
        p.send_signal(2)
    _, err = p.communicate(timeout=300)
    assert p.returncode in (0, 130), err[-500:]
    if p.returncode == 130:
        assert "Traceback" not in err
    man = _atomic.read_manifest(out)  # every listed file present and unchanged
    assert set(man["files"]) == {q.name for q in out.iterdir()} - {_atomic.MANIFEST}
    doc = json.loads((out / "summary.json").read_text())
    assert doc["seed"] in (1, 2) and json.loads(js.read_text()) == doc
    if p.returncode == 0:
        assert doc["seed"] == 2
