"""Both measured-amplification estimators on a folder of native OpenACC files
(issue 28, item 2): per follower the band RMS ratio and the H1 band gain with its
coherence and interval, then their agreement.

    cd ../shared/data/openacc-zalazone
    python $REPO/benches/amplification_fielddata.py short_setting long_setting mixed no_ACC

Prints one line per follower and a summary: followers, those with both estimates,
why the others have none, the median and quartiles of ratio / H1, the share of
followers whose ratio exceeds H1, the median coherence and the share of ratios inside
H1's 95 % interval. (A follower's own disturbance inflates the ratio and not H1; see
docs/guide/amplification.md.)
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter

import numpy as np

from avll.io.openacc_native import openacc_native_report
from avll.spectral import h1_band_gain
from avll.studies.openacc import MIN_EXCITATION, amplification


def main(argv: list[str] | None = None) -> int:
    """Runs the comparison on the folder given on the command line."""
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("paths", nargs="+", help="native OpenACC files or folders")
    args = ap.parse_args(argv)
    runs = [r for p in args.paths for r in openacc_native_report(p)[0]]
    rows, why = [], Counter()
    for r in runs:
        if r.lead_v is None or r.v is None:
            continue
        try:
            ratio, _, rp = amplification(r.v, r.lead_v, r.dt)
        except ValueError as e:
            why[f"ratio: {e}"] += 1
            continue
        g = h1_band_gain(r.lead_v, r.v, r.dt)
        if rp < MIN_EXCITATION:
            why["ratio: the predecessor does not excite"] += 1
            continue
        if g.gain is None or g.ci is None:
            why[f"H1: {(g.reason or '').split(':')[0].split(' gives')[0]}"] += 1
            continue
        rows.append((r.run_id, ratio, g.gain, g.ci, g.coherence))
        print(f"{r.run_id}: ratio {ratio:.3f}, H1 {g.gain:.3f} [{g.ci[0]:.3f}, "
              f"{g.ci[1]:.3f}], coherence {g.coherence:.2f}")
    n = len(rows) + sum(why.values())
    print(f"\n{n} followers, {len(rows)} with both estimates; without: {dict(why)}")
    if rows:
        q = np.array([a / b for _, a, b, _, _ in rows])
        coh = np.array([c for *_, c in rows])
        inside = np.mean([ci[0] <= a <= ci[1] for _, a, _, ci, _ in rows])
        lo, hi = np.quantile(q, [0.25, 0.75])
        print(f"ratio / H1: median {np.median(q):.3f} (quartiles {lo:.3f}-{hi:.3f}); "
              f"ratio > H1 for {np.mean(q > 1):.2f} of followers; median coherence "
              f"{np.median(coh):.2f}; ratio inside H1's 95 % interval for {inside:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
