"""``avll synth``: the synthetic 21-run experiment in the canonical format."""

from __future__ import annotations

import argparse

from ._common import add_model, add_seed, declare_io


def _cmd(args: argparse.Namespace) -> int:
    from .. import PAPER_TABLE_II
    from ..io import write_runs
    from ..synth import paper_experiment

    runs = paper_experiment(PAPER_TABLE_II[args.model], seed=args.seed, duration=args.duration,
                            noise_a=args.noise_a, quantization_a=args.quantization)
    path = write_runs(runs, args.out)
    n = sum(len(r) for r in runs)
    print(f"wrote {len(runs)} runs ({n} samples, model {args.model}, seed {args.seed}) to {path}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Registers ``avll synth``."""
    from ..defaults import SYNTH_DURATION, SYNTH_NOISE

    p = sub.add_parser(
        "synth", help="write the synthetic 21-run experiment in the canonical format",
        description="Generate the paper's 21-run experiment (Table I) with a known true "
        "lower level (Table II parameters), sensor noise and quantization, and write it "
        "in the canonical format (CSV or Parquet, with a .meta.json sidecar). The runs "
        "are synthetic and labelled so in their metadata.")
    p.add_argument("--out", required=True, metavar="FILE",
                   help="output CSV or Parquet file (required; no default)")
    add_model(p, "proposed", "true lower-level model, with its Table II parameters")
    add_seed(p, "noise")
    p.add_argument("--duration", type=float, default=SYNTH_DURATION,
                   help=f"seconds per run (default: {SYNTH_DURATION:g})")
    p.add_argument("--noise-a", type=float, default=(a := SYNTH_NOISE["noise_a"]),
                   help=f"acceleration noise standard deviation in m/s² (default: {a:g})")
    p.add_argument("--quantization", type=float, default=(q := SYNTH_NOISE["quantization_a"]),
                   help=f"acceleration quantization step in m/s² (default: {q:g})")
    declare_io(p, files=("out",), runs=("out",))
    p.set_defaults(func=_cmd)
