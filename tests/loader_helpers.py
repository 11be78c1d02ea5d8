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
NO_DATA = f"measured data not found at {DATA} (../shared/data beside the repository)"

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
