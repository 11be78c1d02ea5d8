"""The paper's three Table II models on a built-in command (``avll simulate``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from . import PAPER_TABLE_II, _atomic, plotting
from ._limits import check_memory, check_number
from .rollout import simulate


def demo_command(dt: float = 0.05, duration: float = 60.0) -> np.ndarray:
    """A built-in command acceleration (m/s²): 1 for the first 10 s, -0.5 for the next
    10 s (two steps), then a 0.1 Hz sine of amplitude 0.8 to the end."""
    t = np.arange(0.0, duration, dt)
    return np.select([t < 10, t < 20], [1.0, -0.5], 0.8 * np.sin(2 * np.pi * 0.1 * (t - 20)))


def run(out: Path, dt: float = 0.05) -> dict[str, np.ndarray]:
    """Simulates the three Table II models; writes ``simulate.csv`` and ``simulate.png``
    into ``out`` as one unit (a ``MANIFEST.json`` is written last, see
    :mod:`avll._atomic`)."""
    import matplotlib

    matplotlib.use("Agg")

    dt = check_number(dt, "dt", positive=True)
    if dt > 10.0:
        raise ValueError(f"dt: {dt:g} s is longer than the demo command's 10 s steps; "
                         "use <= 10 s")
    check_memory(8.0 * 8 * 60.0 / dt, f"simulate: 60 s at dt={dt:g} s x 8 series",
                 "use a larger dt")
    u = demo_command(dt)
    t = np.arange(u.size) * dt
    res = {name: simulate(m, u, dt) for name, m in PAPER_TABLE_II.items()}
    cols = np.column_stack([t, u, *res.values()])
    with _atomic.output_dir(Path(out), meta={"command": "avll simulate"}) as stage:
        with _atomic.atomic_path(stage / "simulate.csv") as tmp:
            # t to the step's precision, accelerations to 1e-6 m/s² (the rollout's
            # accuracy is far finer; more digits would only print float noise)
            fmt = ["%.10g", "%.6g"] + ["%.6g"] * len(res)
            np.savetxt(tmp, cols, delimiter=",", header="t,command," + ",".join(res),
                       comments="", fmt=fmt)
        fig = plotting.traces(t, None, res, command=u,
                              title="Table II models on the built-in command (simulated)")
        _atomic.savefig(fig, stage / "simulate.png", dpi=120)
    return res
