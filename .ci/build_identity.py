"""Seeded calibrations whose every bit is compared between two builds of avll.

``python .ci/build_identity.py dump OUT.json`` runs, with whatever ``import avll``
finds, a fixed set of seeded calibrations (one start and several, stopped at a target
or not, every model, many problems, closed loop with free upper-level gains) on 1 and
2 threads, plus the Eq. 6 costs of fixed parameter sets, and writes their evaluation
counts, costs, parameters and cost histories (floats as hex, so exactly) with the
extension's path and build.

``python .ci/build_identity.py compare A.json B.json`` exits 1, listing each case
that differs, unless the two dumps agree in every value. It refuses (exit 1) to
compare builds of different sources (``avll._core.SOURCE_DIGEST``, see build.rs):
such a comparison says nothing about the builds. That is how abi3 came to be blamed
for a search difference that two source trees made (docs/development.md, "abi3").
``.ci/run`` dumps once with the abi3 wheel installed in a venv without a Rust
toolchain and once with a version-specific build of the same sources, and compares.

Each dump also checks itself: every case must give the same values on 1 and 2
threads (``dump`` exits 1 otherwise).
"""

from __future__ import annotations

import hashlib
import json
import sys
from typing import Any

import numpy as np


def _hex(values: Any) -> list[str]:
    return [float(v).hex() for v in np.ravel(np.asarray(values, dtype=np.float64))]


def _result(r: Any) -> dict[str, Any]:
    return {
        "evaluations": int(r.evaluations),
        "generations": int(r.generations),
        "stop": str(r.stop),
        "cost": float(r.cost).hex(),
        "params": {k: float(v).hex() for k, v in r.params.items()},
        "upper": {k: float(v).hex() for k, v in r.upper.items()},
        "start_costs": _hex(r.start_costs),
        "history": hashlib.sha256("".join(_hex(r.history)).encode()).hexdigest(),
    }


def cases() -> dict[str, Any]:
    """Every case on 1 and 2 threads: ``{name: {"t1": ..., "t2": ...}}``."""
    import avll
    from avll.calibration import calibrate, calibrate_many
    from avll.synth import paper_experiment

    data = paper_experiment(avll.PAPER_TABLE_II["proposed"], seed=11, duration=90.0)
    cal = data[:4]
    rng = np.random.default_rng(0)
    lo = np.array([1e-4, 1e-3, 1e-3, 0.0, 0.0, -3.0])
    hi = np.array([100.0, 100.0, 100.0, 3.0, 3.0, 3.0])
    points = lo + rng.random((64, 6)) * (hi - lo)
    out: dict[str, Any] = {}

    def both(name: str, run: Any) -> None:
        out[name] = {f"t{t}": run(t) for t in (1, 2)}

    both("batch_cost", lambda t: _hex(avll.batch_cost("proposed", points, cal, threads=t)))
    both("proposed_seed5", lambda t: _result(
        calibrate("proposed", cal, seed=5, max_generations=25, threads=t)))
    for seed in (0, 3):
        full = calibrate("proposed", cal, seed=seed, max_generations=30, threads=1)
        out[f"proposed_seed{seed}_full"] = {"t1": _result(full)}
        for factor in (1.05, 1.2):
            target = full.cost * factor
            both(f"proposed_seed{seed}_3starts_target{factor}", lambda t, s=seed, g=target: _result(
                calibrate("proposed", cal, seed=s, max_generations=30, target=g, starts=3,
                          threads=t)))
    both("second_2starts", lambda t: _result(
        calibrate("second", cal, seed=2, max_generations=20, starts=2, threads=t)))
    both("first", lambda t: _result(calibrate("first", cal, seed=1, threads=t)))
    both("second_many", lambda t: [_result(r) for r in calibrate_many(
        "second", cal, "per_run", seed=9, max_generations=15, threads=t)])
    both("first_closed_loop_upper", lambda t: _result(calibrate(
        "first", cal[:2], seed=4, closed_loop=True, upper_free=("kv",), max_generations=8,
        threads=t)))
    return out


def dump(path: str) -> int:
    from avll import _core

    got = cases()
    racy = sorted(k for k, v in got.items() if "t2" in v and v["t1"] != v["t2"])
    doc = {"extension": _core.__file__, "source_digest": _core.SOURCE_DIGEST, "cases": got}
    with open(path, "w", encoding="utf-8") as f:
        json.dump(doc, f, indent=1, sort_keys=True)
    print(f"{len(got)} cases from {_core.__file__} -> {path}")
    if racy:
        print(f"differ between 1 and 2 threads: {', '.join(racy)}")
        return 1
    return 0


def compare(a_path: str, b_path: str) -> int:
    with open(a_path, encoding="utf-8") as f:
        a = json.load(f)
    with open(b_path, encoding="utf-8") as f:
        b = json.load(f)
    print(f"A: {a['extension']} (sources {a.get('source_digest')})")
    print(f"B: {b['extension']} (sources {b.get('source_digest')})")
    if a.get("source_digest") is None or a.get("source_digest") != b.get("source_digest"):
        print("REFUSED: the two extensions were not built from the same sources, so their "
              "differences would say nothing about how they were built")
        return 1
    names = sorted(set(a["cases"]) | set(b["cases"]))
    bad = [n for n in names if a["cases"].get(n) != b["cases"].get(n)]
    for n in bad:
        ea, eb = a["cases"].get(n), b["cases"].get(n)

        def evals(e: Any) -> Any:
            if not isinstance(e, dict):
                return e
            r = e.get("t1")
            if isinstance(r, list):
                return [x.get("evaluations") for x in r]
            return r.get("evaluations") if isinstance(r, dict) else "(costs)"

        print(f"DIFFERS {n}: evaluations {evals(ea)} vs {evals(eb)}")
    print(f"{len(names) - len(bad)} of {len(names)} cases identical bit for bit")
    return 1 if bad else 0


def main(argv: list[str]) -> int:
    if len(argv) == 2 and argv[0] == "dump":
        return dump(argv[1])
    if len(argv) == 3 and argv[0] == "compare":
        return compare(argv[1], argv[2])
    print(__doc__.strip().splitlines()[0], file=sys.stderr)
    print("usage: build_identity.py dump OUT.json | compare A.json B.json", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
