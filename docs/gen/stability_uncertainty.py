"""Generates the uncertainty section of docs/stability.md: the minimum stable Tg of
the proposed model as a distribution over bootstrap resamples of a calibration, and
the probability of stability near it. The calibration data are the synthetic paper
experiment (``avll.synth.paper_experiment``, Table II parameters plus the synthetic
noise), so the spread shows what that experiment identifies, not field data.

    python -m docs.gen --only stability-uncertainty     # 20 bootstrap calibrations
"""

from __future__ import annotations

import time

import numpy as np

import avll
from avll.synth import paper_experiment


def render(n: int = 20, seed: int = 0, distributed: bool = False) -> str:
    """The fragment's body (``distributed``: on a local dask.distributed cluster of two
    workers)."""
    t0 = time.perf_counter()
    runs = paper_experiment(avll.PAPER_TABLE_II["proposed"], seed=1)
    client = avll.maps.local_client() if distributed else None
    try:
        if client is not None:
            bs = avll.maps.bootstrap_distributed("proposed", runs, n=n, seed=seed,
                                                 client=client)
        else:
            bs = avll.bootstrap("proposed", runs, n=n, seed=seed)
        models = avll.models_from_bootstrap(bs)
        d = avll.min_stable_tg_samples(models, client=client, distributed=client is not None)
        e = avll.min_stable_tg(avll.PAPER_TABLE_II["proposed"])
        kg = np.array([0.1])
        kv = np.array([0.4])
        b = float(avll.boundary(avll.PAPER_TABLE_II["proposed"], "tg_min", kg=kg, kv=kv)[0, 0])
        tg = np.round(b + np.array([-0.1, -0.05, -0.02, 0.0, 0.02, 0.05, 0.1]), 3)
        p = avll.stability_probability(models, kg, tg, kv).values[0, :, 0]
    finally:
        if client is not None:
            cl = client.cluster
            client.close()
            cl.close()
    v = d["tg_min"].values
    md = [
        f"Proposed model, {n} bootstrap resamples (seed {seed}) of a calibration on the "
        "synthetic paper experiment (`avll.synth.paper_experiment`, seed 1); per resample the "
        "infimum of the stable Tg over kg in [1e-3, 2], kv in [0, 1.2] (Padé 2):",
        "",
        "| statistic | inf Tg (s) |",
        "|---|---|",
        f"| 5 % quantile | {d.attrs['q05']:.4f} |",
        f"| median | {d.attrs['q50']:.4f} |",
        f"| 95 % quantile | {d.attrs['q95']:.4f} |",
        f"| min / max | {np.nanmin(v):.4f} / {np.nanmax(v):.4f} |",
        f"| Table II parameters | {e.value:.4f} |",
        "",
        "Probability of stability over the resamples at kg = 0.1, kv = 0.4, around the "
        f"Table II boundary there (smallest stable Tg {b:.4f} s):",
        "",
        "| Tg (s) | " + " | ".join(f"{t:g}" for t in tg) + " |",
        "|---|" + "---|" * tg.size,
        "| P(stable) | " + " | ".join(f"{x:.2f}" for x in p) + " |",
        "",
        f"_Computed in {time.perf_counter() - t0:.0f} s._",
    ]
    return "\n".join(md)
