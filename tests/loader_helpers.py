"""Small synthetic files in the published formats, for the loader tests."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pandas as pd

#: The shared measured data (``../shared/data`` from the repository root).
DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
CARMA = DATA / "carma"
ASTA = DATA / "openacc-astazero"
#: The one skip reason of the tests that need the field data: where it is looked for and
#: how to get it (the folders the tests read: docs/data.md, "Running the tests").
NO_DATA = (f"field data not found at {DATA}; get it with `avll data fetch NAME --dest "
           f"{DATA}/FOLDER` (carma -> carma, astazero-c2art -> openacc-astazero, "
           "openacc-casale -> 'openacc-jrc/Casale', ...: see docs/data.md)")

CARMA_SUFFIXES = ("CARMA_mode", "Speed_command", "CARMA_ovr", "avg_speed_driven_wheels",
                  "ACC_speed", "ACC_status", "GPS_CARMA_speed", "GPS_speed", "acceleration",
                  "fuel_consumption", "CARMA_ovr_manual", "radar1")


def sha(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def carma_frame(n: int = 600, vehicles: tuple[str, ...] = ("leader", "follower1"),
                seed: int = 0) -> pd.DataFrame:
    """A CARMA-like table, 10 Hz, all vehicles engaged (mode 2, command > 0) and
    consistent: speed follows the command through a first-order lag, acceleration is
    the speed's derivative quantised to 0.1 m/s²."""
    rng = np.random.default_rng(seed)
    t = np.round(np.arange(n) * 0.1, 1)
    cols: dict[str, object] = {"Date": ["17/07/2018"] * n, "Heure": ["13:44:00"] * n, "Time": t}
    for k, v in enumerate(vehicles):
        cmd = 15 + 3 * np.sin(2 * np.pi * t / (20 + 5 * k)) + 0.1 * rng.standard_normal(n)
        spd = np.empty(n)
        spd[0] = cmd[0]
        for i in range(1, n):
            spd[i] = spd[i - 1] + 0.1 * (cmd[i - 1] - spd[i - 1]) / 0.8
        acc = np.round(np.gradient(spd, 0.1), 1)
        vals = {"CARMA_mode": np.full(n, 2.0), "Speed_command": cmd, "CARMA_ovr": np.ones(n),
                "avg_speed_driven_wheels": spd, "ACC_speed": np.full(n, 20.0),
                "ACC_status": np.ones(n), "GPS_CARMA_speed": spd, "GPS_speed": spd,
                "acceleration": acc, "fuel_consumption": np.ones(n),
                "CARMA_ovr_manual": np.full(n, np.nan), "radar1": np.full(n, 30.0)}
        for s in CARMA_SUFFIXES:
            cols[f"{v}_{s}"] = vals[s]
    return pd.DataFrame(cols)


def canonical_frame(n: int = 400, runs: tuple[str, ...] = ("r1", "r2"), dt: float = 0.05,
                    seed: int = 0) -> pd.DataFrame:
    """A long canonical table (run, t, command, a, v, x) with plausible SI signals."""
    rng = np.random.default_rng(seed)
    parts = []
    for j, r in enumerate(runs):
        t = np.arange(n) * dt
        a = 0.8 * np.sin(2 * np.pi * t / (8 + j)) + 0.02 * rng.standard_normal(n)
        v = 12 + np.cumsum(a) * dt
        x = np.cumsum(v) * dt
        cmd = np.r_[a[3:], np.repeat(a[-1], 3)]
        parts.append(pd.DataFrame({"run": r, "t": t, "command": cmd, "a": a, "v": v, "x": x}))
    return pd.concat(parts, ignore_index=True)


LABELS_HEADER = ("File,type1,type2,type3,atf1,atf2,atf3,atb1,atb2,atb3,"
                 "length1,length2,length3\n")


def openacc_dir(root: Path, n: int = 600, stem: str = "ASta_010101_platoon1") -> Path:
    """A small 3-car OpenACC-like platoon file with its Labels.csv and Slope.csv in
    ``root``; returns the platoon file. Spacing = X_{i-1} - X_i - length_{i-1}."""
    lap = 1000.0
    sx = np.arange(0.0, lap + 1e-9, 5.0)
    pd.DataFrame({"X": sx, "Y": 0.02 * np.sin(2 * np.pi * sx / lap)}).to_csv(
        root / "Slope.csv", index=False)
    lengths = (5.0, 4.5, 4.8)
    (root / "Labels.csv").write_text(
        LABELS_HEADER + f"{stem},1,2,3,4,3.5,4,0.6,1,0.7,{lengths[0]},{lengths[1]},{lengths[2]}\n",
        encoding="utf-8")
    t = np.round(1.0 + 0.1 * np.arange(n), 1)
    cols: dict[str, np.ndarray] = {"Time": t}
    v_lead = 15 + 2 * np.sin(2 * np.pi * t / 30)
    x_prev = 900.0 + np.cumsum(v_lead) * 0.1
    vs, xs = [v_lead], [x_prev]
    for _ in range(2):
        v = np.r_[vs[-1][0], vs[-1][:-1]]  # a 0.1 s lagged copy
        xs.append(xs[-1] - lengths[len(xs) - 1] - 20.0 - 0.5 * np.sin(t))
        vs.append(v)
    for i in range(3):
        cols[f"X{i + 1}"] = xs[i]
    for i in range(3):
        cols[f"SpeedDoppler{i + 1}"] = vs[i]
    for i in range(3):
        cols[f"Accel{i + 1}"] = np.r_[np.diff(vs[i]) / 0.1, 0.0]
    for i in range(1, 3):
        cols[f"Spacing{i + 1}"] = xs[i - 1] - xs[i] - lengths[i - 1]
    p = root / f"{stem}.csv"
    pd.DataFrame(cols).to_csv(p, index=False)
    return p


ZALA = DATA / "openacc-zalazone"

#: Car names of the synthetic native OpenACC files.
NATIVE_NAMES = ("SMART_TARGET", "TESLA_MODEL3", "BMW_I3", "AUDI_A4", "MAZDA_3", "TOYOTA_RAV4")


def native_platoon(n: int = 900, vehicles: int = 4, *, dt: float = 0.1, radius: float = 150.0,
                   seed: int = 0, tg: float = 1.5) -> dict[str, np.ndarray]:
    """A consistent platoon on a circle: the leader's speed oscillates at 0.05 Hz, the
    followers run a constant-time-gap law on a first-order lag. Returns ``t`` and per
    vehicle ``i`` (1-based) ``Speed{i}, E{i}, N{i}, Alt{i}, s{i}`` and ``IVS{i}`` (the
    straight-line distance minus 4 m), plus the true acceleration ``a{i}``."""
    rng = np.random.default_rng(seed)
    t = 100.0 + dt * np.arange(n)
    v = np.zeros((vehicles, n))
    a = np.zeros((vehicles, n))
    s = np.zeros((vehicles, n))
    v[0] = 8.0 + 0.5 * np.sin(2 * np.pi * 0.05 * (t - t[0]))
    a[0] = 0.5 * 2 * np.pi * 0.05 * np.cos(2 * np.pi * 0.05 * (t - t[0]))
    s[0] = np.concatenate([[0.0], np.cumsum(0.5 * (v[0][1:] + v[0][:-1]) * dt)]) + 400.0
    kg, kv, g0, lag = 0.2, 0.6, 3.0, 0.5
    for i in range(1, vehicles):
        v[i, 0] = v[i - 1, 0]
        s[i, 0] = s[i - 1, 0] - 4.5 - g0 - tg * v[i, 0]
        for k in range(n - 1):
            gap = s[i - 1, k] - s[i, k] - 4.5
            cmd = kg * (gap - tg * v[i, k] - g0) + kv * (v[i - 1, k] - v[i, k])
            a[i, k + 1] = a[i, k] + dt * (cmd - a[i, k]) / lag
            v[i, k + 1] = v[i, k] + 0.5 * dt * (a[i, k] + a[i, k + 1])
            s[i, k + 1] = s[i, k] + 0.5 * dt * (v[i, k] + v[i, k + 1])
    out: dict[str, np.ndarray] = {"t": t}
    for i in range(vehicles):
        th = s[i] / radius
        e, nn = radius * np.cos(th), radius * np.sin(th)
        out[f"Speed{i + 1}"] = v[i] + 0.005 * rng.standard_normal(n)
        out[f"E{i + 1}"], out[f"N{i + 1}"] = e, nn
        out[f"Alt{i + 1}"] = 243.0 + 0.015 * nn
        out[f"s{i + 1}"], out[f"a{i + 1}"] = s[i], a[i]
    for i in range(1, vehicles):
        d = np.hypot(out[f"E{i}"] - out[f"E{i + 1}"], out[f"N{i}"] - out[f"N{i + 1}"])
        out[f"IVS{i}"] = d - 4.0
    return out


def write_native(path: Path, data: dict[str, np.ndarray], *, names: tuple[str, ...] | None = None,
                 n_vehicles: int | None = None, acc: str = "1", setting: str = "L",
                 vehicles: tuple[int, ...] | None = None, empty: dict[str, list[int]] | None = None,
                 date: str = "8,10,2019") -> Path:
    """Writes ``data`` (from :func:`native_platoon`) in the native OpenACC layout;
    ``vehicles`` the vehicle numbers whose columns are written (default all), ``empty``
    cells to leave empty per column (data-row indices)."""
    nv = max(int(k[5:]) for k in data if k.startswith("Speed"))
    vehicles = tuple(range(1, nv + 1)) if vehicles is None else vehicles
    names = NATIVE_NAMES[:nv] if names is None else names
    n_vehicles = nv if n_vehicles is None else n_vehicles
    cols = ["Time"]
    for i in vehicles:
        cols += [f"Speed{i}", f"E{i}", f"N{i}", f"Lon{i}", f"Lat{i}", f"Alt{i}"]
    cols += [f"IVS{i}" for i in range(1, nv) if i in vehicles and i + 1 in vehicles]
    n = data["t"].shape[0]
    table = {"Time": data["t"]}
    for c in cols[1:]:
        if c.startswith(("Lon", "Lat")):
            table[c] = np.full(n, 16.8 if c.startswith("Lon") else 46.9)
        else:
            table[c] = data[c]
    lines = [f"Date,{date}", "Vehicle_order," + ",".join(names) + ",",
             f"Number_of_vehicles,{n_vehicles}", f"ACC,{acc}", f"Distance_setting,{setting}",
             ",".join(cols)]
    holes = {c: set(v) for c, v in (empty or {}).items()}
    for r in range(n):
        cells = []
        for c in cols:
            cells.append("" if r in holes.get(c, ()) else repr(float(table[c][r])))
        lines.append(",".join(cells))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    return path
