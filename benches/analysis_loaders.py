"""Reproduces every number of README § Field data (run from the repository root):

    MPLBACKEND=Agg python benches/analysis_loaders.py [--part carma|grade|closed|all]

Reads ../shared/data (never copies it). Plain least-squares fits with scipy driving
the Rust rollouts of avll; the GA calibration proper is the calibration issue's.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

import avll
from avll.io import carma_report, load_carma, load_openacc_astazero
from avll.io.openacc import grade_at, load_slope

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
G = 9.81


def md(rows: list[list[object]], head: list[str]) -> str:
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        out.append("| " + " | ".join(f"{x:.3g}" if isinstance(x, float) else str(x)
                                     for x in r) + " |")
    return "\n".join(out)


# ---------------------------------------------------------------- CARMA
def carma_runs() -> list[avll.Run]:
    runs = []
    for f in ("data5", "data6", "data9", "data10"):
        runs += load_carma(DATA / "carma" / f"{f}.csv", min_duration=10.0)
    return runs


def sim_speed(model: avll.LowerLevelModel, r: avll.Run) -> tuple[np.ndarray, np.ndarray]:
    """Speed-command rollout from the run's initial steady state: the deviation of the
    command from its first value drives the model from rest; v = v[0] + response."""
    tr = avll.simulate_full(model, r.command - r.command[0], r.dt, command_kind="speed")
    return r.v[0] + tr.v, tr.a


BOUNDS = {  # practical bounds of the paper's parameters for a speed controller
    "first": ([0.05], [10.0]),
    "second": ([0.2, 0.0, 0.05, 0.0], [2.0, 10.0, 10.0, 3.0]),
    "proposed": ([0.0, 0.0, 0.05, 0.05, 0.0, -2.0], [10.0, 10.0, 20.0, 3.0, 3.0, 0.95]),
}
START = {"first": [1.0], "second": [1.0, 0.5, 1.5, 0.5],
         "proposed": [0.5, 0.5, 1.5, 1.0, 0.5, 0.0]}


def fit(name: str, runs: list[avll.Run], target: str,
        warm: np.ndarray | None = None) -> avll.LowerLevelModel:
    """Bounded least squares (scipy) on the Rust rollouts, from a default start and
    from ``warm`` (the nested simpler model's optimum), keeping the better."""
    cls = avll.model_class(name)

    def res(p: np.ndarray) -> np.ndarray:
        m = cls.from_array(p)
        out = []
        for r in runs:
            v, a = sim_speed(m, r)
            e = (a - r.a) if target == "a" else (v - r.v)
            out.append(np.where(np.isfinite(e), e, 1e3) / np.sqrt(len(r) * len(runs)))
        return np.concatenate(out)

    lo, hi = BOUNDS[name]
    best = None
    for x0 in (START[name], warm):
        if x0 is None:
            continue
        x0 = np.clip(x0, np.array(lo) + 1e-9, np.array(hi) - 1e-9)
        sol = least_squares(res, x0, bounds=(lo, hi), x_scale="jac", max_nfev=300)
        if best is None or sol.cost < best.cost:
            best = sol
    return cls.from_array(best.x)


def warm_start(name: str, prev: avll.LowerLevelModel | None) -> np.ndarray | None:
    """The simpler model's optimum expressed in the richer model's parameters."""
    if prev is None:
        return None
    p = prev.to_array()
    if name == "second":  # first-order lag T -> K0=1, m2=0, m3=T, Td=0
        return np.array([1.0, 0.0, p[0], 0.0])
    if name == "proposed":  # second (K0, m2, m3, Td) -> m1=0, K=0
        return np.array([0.0, p[1], p[2], p[0], p[3], 0.0])
    return None


def mse(model: avll.LowerLevelModel, runs: list[avll.Run]) -> tuple[float, float]:
    ea, ev = [], []
    for r in runs:
        v, a = sim_speed(model, r)
        ea.append(np.mean((a - r.a) ** 2))
        ev.append(np.mean((v - r.v) ** 2))
    return float(np.mean(ea)), float(np.mean(ev))


def part_carma() -> None:
    runs = carma_runs()
    rep = carma_report(runs)
    print("## CARMA stretches (min_duration 10 s, max_hole 0.2 s)\n")
    print(md([list(r) for r in rep.itertuples(index=False)], list(rep.columns)))
    notes = {}
    for r in runs:
        notes[r.meta["file"]] = r.meta["file_report"]["notes"]
    for f, n in notes.items():
        print(f"- {Path(f).name}: {'; '.join(n) or 'no file-level cleaning'}")
    durs = np.array([(len(r) - 1) * r.dt for r in runs])
    print(f"\n{len(runs)} stretches, {durs.sum() / 60:.1f} min in total; median "
          f"{np.median(durs):.0f} s, max {durs.max():.0f} s; bridged samples "
          f"{sum(r.meta['bridged_samples'] for r in runs)}")
    q = sorted({v["a_quantum"] for r in runs for v in r.meta["file_report"]["vehicles"].values()})
    print(f"acceleration quantum estimates: {q}")
    dv = np.concatenate([np.gradient(r.v, r.dt) for r in runs])
    a = np.concatenate([r.a for r in runs])
    print(f"slope of d(wheel speed)/dt on CAN acceleration: {np.dot(dv, a) / np.dot(a, a):.3f}; "
          f"share of a == 0: {np.mean(a == 0):.2f}")
    err = np.concatenate([r.v - r.command for r in runs])
    print(f"speed - command: median {np.median(err):+.3f} m/s, 5-95 % "
          f"[{np.quantile(err, 0.05):+.2f}, {np.quantile(err, 0.95):+.2f}] m/s\n")

    print("## Paper's Table II models driven by the CARMA speed command\n")
    rows = []
    for name, m in avll.PAPER_TABLE_II.items():
        ma, mv = mse(m, runs)
        lin = m.linear()
        dc = lin["b0"] / (1 - lin["K"] * lin["b0"])
        rows.append([name, dc, ma, mv])
    print(md(rows, ["model (Table II)", "DC gain", "MSE a (m²/s⁴)", "MSE v (m²/s²)"]))

    print("\n## Least-squares fits per vehicle (calibrate on data5+data9, validate on "
          "data6+data10; objective: acceleration MSE)\n")
    vehicles = ["leader", "follower1", "follower2", "follower3", "follower4"]
    cal_files = ("data5", "data9")
    rows = []
    best_models = {}
    for veh in vehicles:
        vr = [r for r in runs if r.meta["vehicle"] == veh]
        cal = [r for r in vr if r.run_id.split("/")[0] in cal_files]
        val = [r for r in vr if r.run_id.split("/")[0] not in cal_files]
        prev = None
        for name in ("first", "second", "proposed"):
            m = fit(name, cal, "a", warm_start(name, prev))
            prev = m
            ca, cv = mse(m, cal)
            va, vv = mse(m, val)
            rows.append([veh, name, ca, va, cv, vv, " ".join(f"{x:.3g}" for x in m.to_array())])
            if name == "second":
                best_models[veh] = m
        print(f"  fitted {veh}", file=sys.stderr)
    print(md(rows, ["vehicle", "model", "cal MSE a", "val MSE a", "cal MSE v", "val MSE v",
                    "params (paper order)"]))

    print("\n## Asymmetric first-order lag: dv/dt = (cmd(t - d) - v) / T, T = T_up when "
          "cmd(t - d) > v and T_down otherwise; grid search on the acceleration MSE "
          "(Eq. 6: mean over stretches), launch stretches (from standstill) and cruise "
          "stretches separately\n")
    rows = []
    tgrid = np.round(np.r_[0.05, np.arange(0.1, 1.0, 0.1), np.arange(1.0, 8.01, 0.2)], 2)
    tu, td_ = (g.ravel() for g in np.meshgrid(tgrid, tgrid, indexing="ij"))
    sym = np.flatnonzero(tu == td_)
    for veh in vehicles:
        for regime in ("launch", "cruise"):
            vr = [r for r in runs if r.meta["vehicle"] == veh
                  and ((r.v[0] < 1.0) == (regime == "launch"))]
            vr = [r for r in vr if (regime == "cruise") or r.v.max() < 22.0]
            if not vr:
                continue
            best_sym, best_asym = None, None
            for d in (0, 2, 4, 6):
                m = np.zeros(tu.size)
                for r in vr:
                    u = np.r_[np.full(d, r.command[0]), r.command[: len(r) - d]]
                    v = np.full(tu.size, r.v[0])
                    sse = np.zeros(tu.size)
                    for n in range(len(r)):
                        e = u[n] - v
                        a = e / np.where(e > 0, tu, td_)
                        sse += (a - r.a[n]) ** 2
                        v = v + r.dt * a
                    m += sse / len(r) / len(vr)
                i = int(np.argmin(m))
                j = int(sym[np.argmin(m[sym])])
                if best_asym is None or m[i] < best_asym[0]:
                    best_asym = (float(m[i]), d * 0.1, float(tu[i]), float(td_[i]))
                if best_sym is None or m[j] < best_sym[0]:
                    best_sym = (float(m[j]), d * 0.1, float(tu[j]))
            rows.append([veh, regime, len(vr), best_sym[1], best_sym[2], best_sym[0],
                         best_asym[1], best_asym[2], best_asym[3], best_asym[0]])
        print(f"  asymmetric lag {veh}", file=sys.stderr)
    print(md(rows, ["vehicle", "stretches", "n", "sym d (s)", "sym T (s)", "sym MSE a",
                    "asym d (s)", "T_up (s)", "T_down (s)", "asym MSE a"]))

    print("\nHow the command relates to the speed: mean |cmd[n] - v[n + k]| by lag k\n")
    rows = []
    for regime in ("launch", "cruise"):
        rr = [r for r in runs if (r.v[0] < 1.0) == (regime == "launch")]
        vals = []
        for k in (0, 5, 10, 20, 30):
            e = np.concatenate([r.command[: len(r) - k] - r.v[k:] for r in rr])
            vals.append(float(np.mean(np.abs(e))))
        rows.append([regime, len(rr), *vals])
    print(md(rows, ["stretches", "n", "k=0", "0.5 s", "1 s", "2 s", "3 s"]))


# ---------------------------------------------------------------- grade
def hp(y: np.ndarray, w: int) -> np.ndarray:
    return y - np.convolve(y, np.ones(w) / w, mode="same")


def part_grade() -> None:
    asta = DATA / "openacc-astazero"
    sx, sy, lap = load_slope(asta / "platoon" / "Slope.csv")
    print("## OpenACC AstaZero\n")
    print(f"Slope.csv: {sx.size} points, lap {lap:.3f} m, grade in [{sy.min():.4f}, "
          f"{sy.max():.4f}], net rise over the lap {np.trapezoid(sy, sx):+.3f} m")
    runs = load_openacc_astazero(asta)
    rows = []
    for r in runs:
        if r.meta["kind"] == "platoon":
            rows.append([r.run_id, len(r), (len(r) - 1) * r.dt, float(r.v.max()),
                         r.meta["lead_length"], r.meta["spacing_max_deviation"]])
    print(md(rows, ["pair", "samples", "duration s", "max v", "lead length m",
                    "max |lead_x - x - Spacing| m"]))
    rows = []
    for r in runs:
        if r.meta["kind"] == "freeflow":
            rows.append([r.run_id, (len(r) - 1) * r.dt, r.meta["set_speed"], float(r.v.mean()),
                         float(r.v.std()), float(np.mean(r.v - r.meta["set_speed"]))])
    print()
    print(md(rows, ["free flow", "duration s", "set speed", "mean v", "std v",
                    "mean v - set"]))
    # acceleration is a forward difference of the speed
    r0 = runs[-1]
    fwd = np.diff(r0.v) / r0.dt
    print(f"\nAccel = forward difference of SpeedDoppler: max |diff| "
          f"{np.max(np.abs(fwd - r0.a[:-1])):.2g} m/s² ({r0.run_id})")

    print("\nGrade offset scan (free flow; high-passed acceleration, 4 s window, vs "
          "-g grade((x + offset) mod lap)):\n")
    offs = np.arange(-60.0, 81.0, 1.0)
    groups: dict[float, list[avll.Run]] = {}
    for r in runs:
        if r.meta["kind"] == "freeflow":
            groups.setdefault(round(r.meta["set_speed"], 2), []).append(r)
    rows = []
    w = 40
    for vset, rr in sorted(groups.items()):
        A = np.concatenate([hp(r.a, w)[w:-w] for r in rr])
        cs = []
        for o in offs:
            D = np.concatenate([hp(-G * grade_at(r.x, (sx, sy, lap), offset=o), w)[w:-w]
                                for r in rr])
            cs.append((np.corrcoef(A, D)[0, 1], np.dot(A, D) / np.dot(D, D)))
        cs = np.array(cs)
        i = int(np.argmax(cs[:, 0]))
        i0 = int(np.flatnonzero(offs == 0)[0])
        near = offs[cs[:, 0] >= cs[i, 0] - 0.02]
        far = [float(cs[int(np.flatnonzero(offs == o)[0]), 0]) for o in (-60.0, 60.0)]
        rows.append([f"{vset * 3.6:.0f} km/h ({len(rr)} files)", offs[i], offs[i] / vset,
                     float(cs[i, 0]), float(cs[i, 1]), float(cs[i0, 0]), float(cs[i0, 1]),
                     f"{near.min():+.0f}..{near.max():+.0f}", f"{far[0]:.2f} / {far[1]:.2f}"])
    print(md(rows, ["set speed", "best offset m", "= s", "corr", "slope", "corr @0",
                    "slope @0", "within 0.02 of best", "corr @-60/+60 m"]))
    # sign check: the opposite sign convention
    rr = [r for r in runs if r.meta["kind"] == "freeflow"]
    A = np.concatenate([hp(r.a, w)[w:-w] for r in rr])
    D = np.concatenate([hp(G * grade_at(r.x, (sx, sy, lap), offset=15.0), w)[w:-w] for r in rr])
    print(f"\nopposite sign (+g grade) at +15 m: corr {np.corrcoef(A, D)[0, 1]:+.2f}")
    # a wrong lap (no modulo: raw X beyond one lap) destroys it
    D = np.concatenate([hp(-G * np.interp(r.x + 15.0, sx, sy), w)[w:-w] for r in rr])
    print(f"no modulo (grade clamped beyond the lap end) at +15 m: corr "
          f"{np.corrcoef(A, D)[0, 1]:+.2f}")
    # lap length: the platoon files cover ~3 laps, so a wrong lap length shifts the
    # grade by k * error on lap k
    series = []
    for r in runs:
        if r.meta["kind"] != "platoon":
            continue
        m = r.v > 5.0
        series.append((r.x[m], r.a[m]))
        if r.meta["leader_index"] == 1:
            series.append((r.lead_x[m] + r.meta["lead_length"], r.lead_a[m]))
    A = np.concatenate([hp(a, w)[w:-w] for _, a in series])
    rows = []
    for dl in (-40.0, -20.0, -10.0, -5.0, 0.0, 5.0, 10.0, 20.0, 40.0):
        cs = []
        for o in (0.0, 15.0):
            D = np.concatenate([hp(-G * grade_at(x, (sx, sy, lap), offset=o,
                                                 lap_length=lap + dl), w)[w:-w]
                                for x, _ in series])
            cs.append(float(np.corrcoef(A, D)[0, 1]))
        rows.append([f"{dl:+.0f}", *cs])
    print("\nPlatoon files (all 10 vehicles, v > 5 m/s): lap-length scan\n")
    print(md(rows, ["lap - 5757.904 m", "corr @ offset 0", "corr @ offset +15 m"]))
    g15 = np.concatenate([grade_at(r.x, (sx, sy, lap), offset=15.0) for r in rr])
    g0 = np.concatenate([grade_at(r.x, (sx, sy, lap)) for r in rr])
    print(f"grade(x+15) - grade(x): RMS {np.sqrt(np.mean((g15 - g0) ** 2)):.4f} vs RMS grade "
          f"{np.sqrt(np.mean(g0 ** 2)):.4f}")


# ---------------------------------------------------------------- closed loop
def closed_pair(r: avll.Run) -> list[object]:
    """Steady-state spacing regression and a quick closed-loop fit of one pair."""
    i0 = int(np.flatnonzero(r.v > 1.0)[0])
    t = slice(i0, len(r))
    lx, lv, am, x, v = r.lead_x[t], r.lead_v[t], r.a[t], r.x[t], r.v[t]
    gap = lx - x
    la = r.lead_a[t]
    calm = (np.abs(am) < 0.05) & (np.abs(la) < 0.05) & (np.abs(v - lv) < 0.2) & (v > 5)
    calm = np.convolve(calm.astype(float), np.ones(31) / 31, mode="same") > 0.999
    tg_ss, gmin_ss = np.polyfit(v[calm], gap[calm], 1) if calm.sum() > 50 else (np.nan,
                                                                              np.nan)
    gr = r.exo["grade"][t]

    def sim(p: np.ndarray) -> avll.Trajectory:
        up = avll.UpperLevel(kg=p[0], kv=p[1], Tg=p[2], Gmin=p[3])
        return avll.closed_loop(avll.FirstOrderLag(Td=p[4]), lx, lv, r.dt, up,
                                v0=float(v[0]), x0=float(x[0]))

    def res(p: np.ndarray) -> np.ndarray:
        tr = sim(p)
        ea = np.where(np.isfinite(tr.a), tr.a - am, 10.0)
        eg = np.where(np.isfinite(tr.x), (lx - tr.x) - gap, 100.0)
        return np.r_[ea, 0.1 * eg] / np.sqrt(am.size)

    best = None
    for x0 in ([0.1, 0.5, 1.0, 3.0, 0.5], [0.05, 0.3, 1.5, 5.0, 1.0],
               [0.2, 0.8, 0.8, 2.0, 0.3]):
        sol = least_squares(res, x0, bounds=([0, 0, 0, 0, 0.05], [2, 3, 5, 20, 5]),
                            x_scale="jac", max_nfev=200)
        if best is None or sol.cost < best.cost:
            best = sol
    tr = sim(best.x)
    e = am - tr.a
    ok = np.isfinite(e)
    gg = -G * gr[ok]
    k_g = float(np.dot(e[ok], gg) / np.dot(gg, gg))
    X = np.c_[np.maximum(tr.a, 0), np.minimum(tr.a, 0)][ok]
    gp, gn = np.linalg.lstsq(X, am[ok], rcond=None)[0]
    return [r.run_id.split("_")[-1], int(calm.sum()), float(tg_ss), float(gmin_ss),
            " ".join(f"{p:.3g}" for p in best.x), float(np.mean(e[ok] ** 2)),
            float(np.mean(((lx - tr.x) - gap)[ok] ** 2)), k_g,
            float(np.corrcoef(e[ok], gg)[0, 1]), float(gp), float(gn)]


def part_closed() -> None:
    asta = DATA / "openacc-astazero"
    runs = load_openacc_astazero(asta / "platoon", command_kind="acceleration")
    print("\n## AstaZero pairs: steady-state spacing and a quick closed-loop fit\n")
    print("Steady state = |a| < 0.05 and |a_lead| < 0.05 and |v - v_lead| < 0.2 over 3 s, "
          "v > 5 m/s; spacing = Gmin + Tg v by least squares. Closed loop: Eq. 3 upper law "
          "+ first-order lower level driven by the measured predecessor (avll.closed_loop),"
          " bounded least squares on acceleration + 0.01 x gap error, best of 3 starts.\n")
    rows = []
    for r in runs:
        rows.append(closed_pair(r))
        print(f"  fitted {r.run_id}", file=sys.stderr)
    print(md(rows, ["pair", "steady samples", "Tg steady (s)", "Gmin steady (m)",
                    "fit kg kv Tg Gmin Td", "MSE a", "MSE gap", "resid. on -g·grade",
                    "corr", "gain a>0", "gain a<0"]))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--part", default="all", choices=["carma", "grade", "closed", "all"])
    a = ap.parse_args()
    if not DATA.is_dir():
        sys.exit(f"measured data not found at {DATA}")
    if a.part in ("carma", "all"):
        part_carma()
    if a.part in ("grade", "all"):
        part_grade()
    if a.part in ("closed", "all"):
        part_closed()


if __name__ == "__main__":
    main()
