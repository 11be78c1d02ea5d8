"""avll's rollout engine against numba peers, side by side in one process.

    python benches/bench_engine.py [--quick] [--repeat 10] [--seconds 1] [--json OUT]
        [--only open,cost] [--allocator default|keep]

The allocator is left as every user runs it (``--allocator keep`` makes glibc keep
freed memory, to time the stepping alone). Each rollout workload (a-c) gives two
tables from one round-robin: without ``out=`` (avll allocates its outputs; the numba
peers allocate theirs per call) and with ``out=`` (avll and the peers write into
arrays allocated once). Ratios are given as the ratio of best times and as the median
and range, over the rounds, of the best peer's CPU time over avll's in the same round
(paired: load hits both alike); the target is judged on the median. Each timed call
is the second of two back-to-back calls of the same implementation (the steady state
of a loop of calls).

Workloads (the paper's Table II proposed model, dt = 0.05 s, at rest):

a. open-loop rollout (``avll.simulate``) of 1e5 and 1e6 samples;
b. closed loop behind a recorded leader (``avll.closed_loop``, upper law Eq. 3);
c. a 20-car platoon (``avll.platoon``);
d. the batched Eq. 6 cost (``avll.batch_cost``): 10,000 parameter sets x one run of
   6,000 samples, and the paper's 10 calibration runs (fewer sets), on 1 and 2
   threads.

Every peer (``benches/peers.py``: a plain numba loop and the best variant we could
write) is first checked equal to avll to 1e-9 of the signal scale on the very inputs
that are timed; a peer that fails stops the benchmark (exit 1). Then each call is
warmed up and timed in round-robin rounds, at least ``--repeat`` of them and until
each implementation has run for ``--seconds`` (a short call is timed hundreds of
times, so that one quiet moment is found for every implementation, not only a long
call's): the rate is work over the best process CPU
time (all threads included, so it is per core even on a shared machine); thread
scaling uses the best wall time. Each table gives avll's rate, every peer's, the
ratio avll / best peer, the issue's target (>= 1.5x the best peer on one core; the
batched cost >= 1.8x faster on 2 threads than on 1) and by how much it is missed.

Only the public API is used (``avll.simulate``, ``closed_loop``, ``platoon``,
``batch_cost``, ``Run``), so the benchmark keeps working when the engine changes
underneath. Build avll in release mode for meaningful numbers
(``maturin develop --release``); numba and cma come with ``pip install avll[bench]``.
"""

from __future__ import annotations

import os

# Idle numba (OpenMP) workers sleep instead of spinning, so that process CPU time
# measures work, not busy-waiting (on a loaded machine spinning doubles it).
os.environ.setdefault("OMP_WAIT_POLICY", "passive")

import argparse  # noqa: E402
import ctypes  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import platform  # noqa: E402
import resource  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable, Sequence  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))

try:
    import peers
except ImportError as e:  # numba missing: one line, not a traceback
    if __name__ != "__main__":
        raise
    sys.exit(f"bench_engine: {e}")

import avll  # noqa: E402
from avll.calibration import DEFAULT_BOUNDS  # noqa: E402
from avll.synth import PAPER_CAL_RUNS, paper_experiment  # noqa: E402

DT = 0.05
MODEL = avll.PAPER_TABLE_II["proposed"]
#: A Table I law (run 3) for one follower.
UPPER_CLOSED = avll.UpperLevel(kg=0.5, kv=0.0, Tg=1.8, Gmin=9.5)
#: A string-stable law for the platoon (Table I's laws amplify along 20 cars of the
#: proposed model until they diverge, which would time NaN handling, not stepping).
UPPER_PLATOON = avll.UpperLevel(kg=0.2, kv=0.2, Tg=3.0, Gmin=9.5)
TARGET_ONE_CORE = 1.5
TARGET_SCALING = 1.8
TOL = 1e-9
#: Closed loops are compared on (at most) their first samples: positions grow to
#: ~7e5 m over 1e6 samples, and the float rounding of two correct implementations
#: drifts apart by a few 1e-9 m there, which the upper law turns into a few 1e-9 of
#: the command's scale (measured: the plain 4x4 peer 2.0e-9 at 1e6 samples, 2.2e-10
#: at 1e5). Within this prefix every peer agrees to 1e-9.
CHECK_SAMPLES = 200_000
NO_TARGET = "the targets apply to one core; thread scaling is reported under 'scaling'"


class PeerMismatch(Exception):
    """A peer does not reproduce avll's numbers; nothing is timed."""


# ---------------------------------------------------------------------------
# Timing and the result table.
# ---------------------------------------------------------------------------


@dataclass
class Timing:
    """Best process CPU time and best wall time (s) of ``calls`` calls."""

    cpu: float
    wall: float
    #: Minor page faults per timed call (mean): fresh output pages the kernel maps.
    faults: float = 0.0
    #: Timed calls.
    calls: int = 0
    #: CPU time of every timed call, round by round (paired across implementations).
    rounds: list[float] = field(default_factory=list)


#: Shortest timed sample (s): a call faster than this is timed as a batch of calls, so
#: that the CPU clock's granularity (tick-based on some machines) cannot round it to 0.
MIN_SAMPLE_S = 0.02


def measure(
    fns: Sequence[Callable[[], object]], repeat: int, seconds: float = 0.0
) -> list[Timing]:
    """Best CPU and wall times of each call, and its mean page faults: one warm-up
    call each, then rounds calling every function in turn (round-robin, so that load
    changes hit every implementation alike), at least ``repeat`` rounds and until the
    rounds took ``seconds`` per function. In a round each function is called once
    untimed and then timed: the state a loop of calls to one implementation runs in
    (its memory and caches as its previous call left them), not the state another
    implementation's call left. A call shorter than :data:`MIN_SAMPLE_S` is timed as
    a batch of back-to-back calls lasting about that long, and the batch's times are
    divided by its size (the CPU clock of some machines advances in ticks of several
    milliseconds: a single short call could read 0)."""
    batch: list[int] = []
    for fn in fns:
        fn()
        w0 = time.perf_counter()
        fn()
        one = time.perf_counter() - w0
        batch.append(max(1, math.ceil(MIN_SAMPLE_S / max(one, 1e-9))))
    cpus: list[list[float]] = [[] for _ in fns]
    walls: list[list[float]] = [[] for _ in fns]
    faults: list[float] = [0.0 for _ in fns]
    start = time.perf_counter()
    rounds = 0
    while rounds < max(1, repeat) or time.perf_counter() - start < 2 * seconds * len(fns):
        rounds += 1
        for k, fn in enumerate(fns):
            n = batch[k]
            fn()
            f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
            w0, c0 = time.perf_counter(), time.process_time()
            for _ in range(n):
                fn()
            cpu, wall = time.process_time() - c0, time.perf_counter() - w0
            if cpu <= 0.0:
                raise RuntimeError(
                    f"the CPU clock read 0 s over {n} call(s) lasting {wall:.3g} s of wall "
                    "time: process_time does not advance on this machine"
                )
            cpus[k].append(cpu / n)
            walls[k].append(wall / n)
            faults[k] += (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0) / n
    return [
        Timing(min(c), min(w), f / rounds, rounds, c)
        for c, w, f in zip(cpus, walls, faults, strict=True)
    ]


#: glibc's mallopt parameters (malloc.h).
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3


def keep_freed_memory() -> str:
    """Makes glibc keep freed memory for reuse (the mmap threshold at its 32 MiB
    maximum, no trimming below 1 GiB), so that no implementation's fresh outputs
    page-fault and the timings measure the stepping. Left to itself, glibc's adaptive
    thresholds decide, from the run's earlier allocations, whether the outputs of a
    call page-fault (each fresh 4 KiB page once; the faults can cost more than the
    stepping), and numpy, which allocates avll's outputs, asks for transparent huge
    pages on arrays of 4 MiB and more, which a numba loop's ``np.empty`` does not.
    Returns what was done, for the report."""
    try:
        libc = ctypes.CDLL("libc.so.6")
        ok = libc.mallopt(_M_MMAP_THRESHOLD, 32 << 20) == 1
        ok &= libc.mallopt(_M_TRIM_THRESHOLD, 1 << 30) == 1
    except (OSError, AttributeError):
        ok = False
    if ok:
        return "glibc keeps freed memory (mallopt: mmap threshold 32 MiB, trim threshold 1 GiB)"
    return "allocator left as it is (not glibc)"


def row(
    name: str,
    variant: str,
    steps: int,
    t: Timing,
    diff: float | None = None,
    extra: dict[str, Any] | None = None,
) -> Row:
    """A result row from a timing (``steps`` per call)."""
    return Row(
        name, variant, steps / t.cpu / 1e6, t.cpu, t.wall, diff,
        {"faults_per_call": t.faults, **(extra or {})}, t.rounds,
    )  # fmt: skip


@dataclass
class Row:
    """One implementation's result on one workload."""

    name: str
    variant: str
    rate: float  # M steps/s
    cpu_s: float
    wall_s: float
    max_rel_diff: float | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    #: CPU time per timed call, round by round (not in the JSON).
    rounds: list[float] = field(default_factory=list)


@dataclass
class Table:
    """One workload: avll's row, the peers' rows, the ratio and the target."""

    key: str
    title: str
    steps: int
    basis: str
    avll: Row
    peers: list[Row]
    target: float | None
    ratio_basis: str = "avll / best peer (M steps/s per core)"
    wall_column: bool = False

    def best_peer(self) -> Row:
        """The fastest peer."""
        return max(self.peers, key=lambda r: r.rate)

    def ratio(self) -> float:
        """avll's rate over the best peer's (best CPU time of each)."""
        return self.avll.rate / self.best_peer().rate

    def paired(self) -> list[float]:
        """Round by round, the best peer's CPU time over avll's in the same round
        (the calls ran back to back, so load hits both alike)."""
        return [p / a for a, p in zip(self.avll.rounds, self.best_peer().rounds, strict=True)]

    def ratio_median(self) -> float:
        """Median of the paired ratios (best-of ratio when no rounds were kept)."""
        r = self.paired()
        return float(np.median(r)) if r else self.ratio()

    def met(self) -> bool | None:
        """Whether the median paired ratio reaches the target."""
        return None if self.target is None else self.ratio_median() >= self.target

    def to_json(self) -> dict[str, Any]:
        """Strict-JSON-ready dict (every number finite)."""
        best = self.best_peer()
        ratio = self.ratio()
        pr = self.paired() or [ratio]
        med = self.ratio_median()
        return {
            "key": self.key,
            "title": self.title,
            "steps_per_call": self.steps,
            "unit": "M steps/s",
            "basis": self.basis,
            "avll": _row_json(self.avll),
            "peers": [_row_json(p) for p in self.peers],
            "best_peer": best.name,
            "ratio": ratio,
            "ratio_basis": self.ratio_basis,
            "ratio_median": med,
            "ratio_range": [min(pr), max(pr)],
            "ratio_quartiles": [float(np.percentile(pr, 25)), float(np.percentile(pr, 75))],
            "paired_rounds": len(pr),
            "target": self.target,
            "met": self.met(),
            "shortfall_factor": None if self.target is None else max(1.0, self.target / med),
            "avll_rate_needed": None if self.target is None else self.target * best.rate,
            **({} if self.target is not None else {"target_reason": NO_TARGET}),
        }


def _row_json(r: Row) -> dict[str, Any]:
    d: dict[str, Any] = {
        "name": r.name,
        "variant": r.variant,
        "rate": r.rate,
        "cpu_s": r.cpu_s,
        "wall_s": r.wall_s,
    }
    if r.max_rel_diff is not None:
        d["max_rel_diff"] = r.max_rel_diff
    d.update(r.extra)
    return d


def verdict(ratio: float, target: float) -> str:
    """``met (...)`` or ``NOT MET: misses by ...``."""
    if ratio >= target:
        return f"met ({ratio / target:.2f}x the target)"
    return f"NOT MET: misses by {target / ratio:.2f}x"


def print_table(t: Table) -> None:
    """One workload's table on stdout."""
    print(f"\n{t.title}")
    print(f"  {t.steps:,} steps per call; {t.basis}")
    w = max(len(r.name) for r in [t.avll, *t.peers]) + 2
    wall = f"{'wall M/s':>10}" if t.wall_column else ""
    print(f"  {'implementation':<{w}}{'M steps/s':>11}{wall}{'max rel diff':>14}{'faults':>8}")
    for r in [t.avll, *t.peers]:
        diff = "" if r.max_rel_diff is None else f"{r.max_rel_diff:.1e}"
        wr = f"{r.extra.get('wall_rate', float('nan')):>10.1f}" if t.wall_column else ""
        flt = f"{r.extra.get('faults_per_call', float('nan')):>8.0f}"
        print(f"  {r.name:<{w}}{r.rate:>11.1f}{wr}{diff:>14}{flt}")
    best = t.best_peer()
    pr = t.paired() or [t.ratio()]
    print(f"  {t.ratio_basis}: {t.ratio():.2f}x best-of (best peer: {best.name})")
    line = (f"  paired per round: median {t.ratio_median():.2f}x, range "
            f"{min(pr):.2f}-{max(pr):.2f}x over {len(pr)} rounds; ")
    if t.target is None:
        line += "no target (informational: " + NO_TARGET + ")"
    else:
        line += f"target >= {t.target}x (median): {verdict(t.ratio_median(), t.target)}"
    print(line)


# ---------------------------------------------------------------------------
# Inputs.
# ---------------------------------------------------------------------------


def command(n: int, seed: int = 1) -> np.ndarray:
    """A smooth random acceleration command."""
    rng = np.random.default_rng(seed)
    return np.ascontiguousarray(np.convolve(rng.normal(size=n), np.ones(10) / 10, mode="same"))


def leader(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A recorded leader: speed oscillating around 15 m/s, exact position."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * DT
    wiggle = np.convolve(rng.normal(scale=0.3, size=n), np.ones(200) / 200, mode="same")
    lv = 15.0 + 3.0 * np.sin(t / 20.0) + 1.5 * np.sin(t / 7.3) + wiggle
    lx = 100.0 + np.concatenate([[0.0], np.cumsum((lv[1:] + lv[:-1]) / 2) * DT])
    return np.ascontiguousarray(lx), np.ascontiguousarray(lv)


def parameter_sets(p: int, seed: int = 2) -> np.ndarray:
    """A GA-like population of the proposed model: 95 % within +-50 % of Table II
    (nearly all stable), 5 % uniform over the calibration box (log scale for m1,
    m2, m3: many unstable); plus, in the first rows, invalid and unstable sets and
    sets with complex poles, so that the ``inf`` semantics are compared too."""
    rng = np.random.default_rng(seed)
    base = MODEL.to_array()
    out = base * rng.uniform(0.5, 1.5, size=(p, base.size))
    wide = rng.random(p) < 0.05
    for j, (lo, hi, scale) in enumerate(DEFAULT_BOUNDS["proposed"].values()):
        z = rng.random(int(wide.sum()))
        out[wide, j] = lo * (hi / lo) ** z if scale == "log" else lo + z * (hi - lo)
    special = np.array(
        [
            [6.8, -1.0, 8.8, 0.35, 0.79, 0.1],  # m2 < 0: invalid
            [6.8, 1.28, 8.8, 0.35, -0.1, 0.1],  # Td < 0: invalid
            [6.8, 1.28, 8.8, 0.35, 0.79, 3.0],  # K K0 > 1: no steady state
            [6.8, 1.28, 8.8, 0.35, 0.79, -40.0],  # delayed feedback oscillates
            [1.0, 1.28, -0.5, 0.35, 0.3, 0.0],  # negative damping
            [0.5, 1.28, 1.0, 0.9, 0.4, 0.1],  # complex poles, stable
            [0.5, 1.28, 0.3, 0.9, 0.2, 0.5],  # complex poles
            [6.8, 1.28, 8.8, 0.35, 0.0, 0.1],  # no dead time
            [6.8, 1.28, 8.8, 0.35, 0.1, 0.1],  # dead time below one sample
        ]
    )
    k = min(p, special.shape[0])
    out[:k] = special[:k]
    return np.ascontiguousarray(out)


# ---------------------------------------------------------------------------
# Workloads.
# ---------------------------------------------------------------------------


def _checked(
    name: str, got: Sequence[Any], want: Sequence[Any], samples: int | None = None
) -> float:
    """Max relative difference over the outputs (the first ``samples`` along the last
    axis when given); raises :class:`PeerMismatch` beyond the tolerance."""
    cut = slice(None) if samples is None else slice(0, samples)
    try:
        return max(
            peers.check_close(name, np.asarray(g)[..., cut], np.asarray(w)[..., cut], TOL)
            for g, w in zip(got, want, strict=True)
        )
    except AssertionError as e:
        raise PeerMismatch(str(e)) from None


def _pair(
    key: str,
    title: str,
    steps: int,
    basis: str,
    avll_name: str,
    t_alloc: Timing,
    t_out: Timing,
    alloc_peers: Sequence[peers.Peer],
    alloc_t: Sequence[Timing],
    alloc_d: Sequence[float],
    into_peers: Sequence[peers.Peer],
    into_t: Sequence[Timing],
    into_d: Sequence[float],
) -> list[Table]:
    """The two tables of one workload: without ``out=`` (avll and the peers allocate
    their outputs per call) and with it (both write into arrays allocated once)."""
    return [
        Table(
            key,
            f"{title}, without out= (outputs allocated per call)",
            steps,
            basis,
            row(avll_name, "avll", steps, t_alloc),
            [row(p.name, p.variant, steps, t, d)
             for p, t, d in zip(alloc_peers, alloc_t, alloc_d, strict=True)],
            TARGET_ONE_CORE,
        ),
        Table(
            f"{key}_out",
            f"{title}, with out= (outputs allocated once)",
            steps,
            basis,
            row(f"{avll_name}(..., out=)", "avll", steps, t_out),
            [row(p.name, p.variant, steps, t, d)
             for p, t, d in zip(into_peers, into_t, into_d, strict=True)],
            TARGET_ONE_CORE,
        ),
    ]


def _same_bits(name: str, got: Sequence[np.ndarray], want: Sequence[np.ndarray]) -> None:
    """avll with ``out=`` must give the allocating call's values bit for bit."""
    for g, w in zip(got, want, strict=True):
        if not np.array_equal(np.asarray(g).view(np.int64), np.asarray(w).view(np.int64)):
            raise PeerMismatch(f"{name}: avll with out= differs from avll without it")


def bench_open(n: int, repeat: int, seconds: float = 0.0) -> list[Table]:
    """(a) open-loop rollout, without and with ``out=``."""
    u = command(n)
    want = avll.simulate(MODEL, u, DT)
    y = np.empty(n)
    _same_bits("open loop", [avll.simulate(MODEL, u, DT, out=y)], [want])
    fns: list[Callable[[], object]] = [
        lambda: avll.simulate(MODEL, u, DT),
        lambda: avll.simulate(MODEL, u, DT, out=y),
    ]
    diffs, into_diffs = [], []
    for p in peers.OPEN_PEERS:
        prep = p.prepare(MODEL, DT)
        diffs.append(_checked(f"open loop, {p.name}", [p.run(prep, u)], [want]))
        fns.append(lambda p=p, prep=prep: p.run(prep, u))
    for p in peers.OPEN_INTO_PEERS:
        prep = p.prepare(MODEL, DT)
        buf = np.empty(n)
        into_diffs.append(_checked(f"open loop, {p.name}", [p.run(prep, u, buf)], [want]))
        fns.append(lambda p=p, prep=prep, buf=buf: p.run(prep, u, buf))
    t, t_out, *tps = measure(fns, repeat, seconds)
    na = len(peers.OPEN_PEERS)
    return _pair(
        f"open_{n}", f"(a) open-loop rollout, proposed model, {n:,} samples", n,
        f"one thread, best CPU time per call over {t.calls} rounds (round-robin)", "avll.simulate",
        t, t_out, peers.OPEN_PEERS, tps[:na], diffs, peers.OPEN_INTO_PEERS, tps[na:],
        into_diffs,
    )  # fmt: skip


def bench_closed(n: int, repeat: int, seconds: float = 0.0) -> list[Table]:
    """(b) closed loop behind a recorded leader, without and with ``out=``."""
    lx, lv = leader(n)
    v0, x0 = float(lv[0]), float(lx[0]) - (UPPER_CLOSED.Gmin + UPPER_CLOSED.Tg * lv[0])

    def call(out: Any = None) -> avll.Trajectory:
        return avll.closed_loop(MODEL, lx, lv, DT, UPPER_CLOSED, v0=v0, x0=x0, out=out)

    tr = call()
    if not np.all(np.isfinite(tr.a)):
        raise PeerMismatch("closed loop: the follower diverges on this leader; nothing timed")
    want = (tr.a, tr.v, tr.x, tr.command)
    mine = tuple(np.empty(n) for _ in range(4))
    _same_bits("closed loop", call(mine).__dict__.values(), want)
    fns: list[Callable[[], object]] = [call, lambda: call(mine)]
    diffs, into_diffs = [], []
    for p in peers.CLOSED_PEERS:
        prep = p.prepare(MODEL, DT)
        got = p.run(prep, UPPER_CLOSED, lx, lv, v0, x0)
        diffs.append(_checked(f"closed loop, {p.name}", got, want, CHECK_SAMPLES))
        fns.append(lambda p=p, prep=prep: p.run(prep, UPPER_CLOSED, lx, lv, v0, x0))
    for p in peers.CLOSED_INTO_PEERS:
        prep = p.prepare(MODEL, DT)
        buf = tuple(np.empty(n) for _ in range(4))
        got = p.run(prep, UPPER_CLOSED, lx, lv, v0, x0, buf)
        into_diffs.append(_checked(f"closed loop, {p.name}", got, want, CHECK_SAMPLES))
        fns.append(lambda p=p, prep=prep, buf=buf: p.run(prep, UPPER_CLOSED, lx, lv, v0, x0, buf))
    del got
    t, t_out, *tps = measure(fns, repeat, seconds)
    na = len(peers.CLOSED_PEERS)
    return _pair(
        f"closed_{n}",
        f"(b) closed loop behind a recorded leader (Eq. 3, kg {UPPER_CLOSED.kg}, "
        f"Tg {UPPER_CLOSED.Tg} s), {n:,} samples",
        n,
        f"one thread, best CPU time per call over {t.calls} rounds (round-robin)"
        + (f"; checked on the first {CHECK_SAMPLES:,} samples" if n > CHECK_SAMPLES else ""),
        "avll.closed_loop", t, t_out, peers.CLOSED_PEERS, tps[:na], diffs,
        peers.CLOSED_INTO_PEERS, tps[na:], into_diffs,
    )  # fmt: skip


def bench_platoon(n: int, followers: int, repeat: int, seconds: float = 0.0) -> list[Table]:
    """(c) platoon behind a recorded leader, without and with ``out=``."""
    lx, lv = leader(n, seed=3)
    up = UPPER_PLATOON

    def call(out: Any = None) -> avll.Trajectory:
        return avll.platoon(MODEL, lx, lv, DT, up, followers, out=out)

    tr = call()
    if not np.all(np.isfinite(tr.a)):
        raise PeerMismatch("platoon: a follower diverges on this leader; nothing timed")
    want = tuple(a.copy() for a in (tr.a, tr.v, tr.x, tr.command))
    # The loop a user writes: each implementation writes into the arrays its own
    # first call returned (avll's are 64-byte aligned blocks; its lane groups store
    # 32 bytes at a time into rows of `followers` doubles).
    mine = call()
    _same_bits("platoon", call(mine).__dict__.values(), want)
    steps = n * followers
    fns: list[Callable[[], object]] = [call, lambda: call(mine)]
    diffs, into_diffs = [], []
    for p in peers.PLATOON_PEERS:
        prep = p.prepare(MODEL, DT)
        diffs.append(
            _checked(f"platoon, {p.name}", p.run(prep, up, lx, lv, followers), want, CHECK_SAMPLES)
        )
        fns.append(lambda p=p, prep=prep: p.run(prep, up, lx, lv, followers))
    twins = {q.variant: q for q in peers.PLATOON_PEERS}
    for p in peers.PLATOON_INTO_PEERS:
        prep = p.prepare(MODEL, DT)
        buf = tuple(twins[p.variant].run(prep, up, lx, lv, followers))
        got = p.run(prep, up, lx, lv, followers, buf)
        into_diffs.append(_checked(f"platoon, {p.name}", got, want, CHECK_SAMPLES))
        fns.append(lambda p=p, prep=prep, buf=buf: p.run(prep, up, lx, lv, followers, buf))
    t, t_out, *tps = measure(fns, repeat, seconds)
    na = len(peers.PLATOON_PEERS)
    return _pair(
        f"platoon_{followers}x{n}",
        f"(c) {followers}-car platoon (Eq. 3, kg {up.kg}, kv {up.kv}, Tg {up.Tg} s), {n:,} samples",
        steps,
        f"one thread, best CPU time per call over {t.calls} rounds (round-robin); "
        "steps = followers x samples"
        + (f"; checked on the first {CHECK_SAMPLES:,} samples" if n > CHECK_SAMPLES else ""),
        "avll.platoon", t, t_out, peers.PLATOON_PEERS, tps[:na], diffs,
        peers.PLATOON_INTO_PEERS, tps[na:], into_diffs,
    )  # fmt: skip


def bench_cost(
    n_params: int,
    runs: list[avll.Run],
    key: str,
    label: str,
    repeat: int,
    threads: Sequence[int],
    seconds: float = 0.0,
) -> tuple[list[Table], dict[str, Any]]:
    """(d) batched Eq. 6 cost: one table per thread count (rates per core, CPU time)
    and the wall-clock scaling from the first to the last thread count."""
    params = parameter_sets(n_params)
    samples = sum(len(r) for r in runs)
    steps = n_params * samples
    want = avll.batch_cost("proposed", params, runs, threads=1)
    if not np.all(np.isfinite(want).sum(axis=0) > 0.5 * n_params):
        raise PeerMismatch(f"batched cost ({label}): most parameter sets cost inf")
    packed = {p.name: p.prepare(runs) for p in peers.COST_PEERS}
    diffs = {}
    for p in peers.COST_PEERS:
        peers.set_threads(max(threads))
        diffs[p.name] = _checked(
            f"batched cost ({label}), {p.name}", [p.run(params, packed[p.name])], [want]
        )
    tables: list[Table] = []
    walls: dict[str, dict[int, float]] = {"avll": {}}
    cpus: dict[str, dict[int, float]] = {"avll": {}}
    for th in threads:

        def peer_call(p: peers.Peer, th: int = th) -> Any:
            peers.set_threads(th)
            return p.run(params, packed[p.name])

        fns: list[Callable[[], object]] = [
            lambda th=th: avll.batch_cost("proposed", params, runs, threads=th)
        ]
        fns += [lambda p=p: peer_call(p) for p in peers.COST_PEERS]
        t, *tps = measure(fns, repeat, seconds)
        walls["avll"][th] = t.wall
        cpus["avll"][th] = t.cpu
        rows = []
        for p, tp in zip(peers.COST_PEERS, tps, strict=True):
            walls.setdefault(p.name, {})[th] = tp.wall
            cpus.setdefault(p.name, {})[th] = tp.cpu
            rows.append(
                row(
                    p.name,
                    p.variant,
                    steps,
                    tp,
                    diffs[p.name],
                    {"wall_rate": steps / tp.wall / 1e6},
                )
            )
        tables.append(
            Table(
                f"cost_{key}_{th}t",
                f"(d) batched Eq. 6 cost, {n_params:,} parameter sets x {label}, {th} thread"
                + ("s" if th > 1 else ""),
                steps,
                f"best CPU time per call over {t.calls} rounds (all threads), i.e. per core; "
                f"{int(np.isinf(want).any(axis=1).sum())} sets cost inf",
                row(
                    f"avll.batch_cost(threads={th})",
                    "avll",
                    steps,
                    t,
                    None,
                    {"wall_rate": steps / t.wall / 1e6},
                ),  # fmt: skip
                rows,
                TARGET_ONE_CORE if th == 1 else None,
                wall_column=True,
            )
        )
    lo, hi = min(threads), max(threads)
    scaling = {
        "key": f"cost_{key}_scaling",
        "title": f"(d) batched Eq. 6 cost, {n_params:,} sets x {label}: "
        f"wall-clock speed-up {hi} threads / {lo}",
        "threads": [lo, hi],
        "speedup": {k: v[lo] / v[hi] for k, v in walls.items()},
        "cpu_efficiency": {k: v[lo] / v[hi] for k, v in cpus.items()},
        "load_average": os.getloadavg()[0],
        "target": TARGET_SCALING,
    }
    scaling["met"] = scaling["speedup"]["avll"] >= TARGET_SCALING
    return tables, scaling


def print_scaling(s: dict[str, Any]) -> None:
    """The thread-scaling line of the batched cost."""
    sp, eff = s["speedup"], s["cpu_efficiency"]
    print(f"\n{s['title']} (best wall time)")
    print(f"  {'':<60}{'wall speed-up':>14}{'CPU efficiency':>16}")
    for k, v in sp.items():
        print(f"  {k:<60}{v:>13.2f}x{eff[k]:>16.2f}")
    print(f"  avll target >= {s['target']}x: {verdict(sp['avll'], s['target'])}")
    hi = s["threads"][1]
    if s["load_average"] > max(0.5, (os.cpu_count() or hi) - hi + 0.5):
        print(
            f"  WARNING: load average {s['load_average']:.1f} on {os.cpu_count()} CPUs: the "
            f"{hi} threads probably did not all have an idle core, so the wall speed-up "
            "is likely understated. CPU efficiency (1-thread CPU time / "
            f"{hi}-thread CPU time for the same work; 1.0 = no parallel overhead) bounds "
            "what idle cores would give: speed-up <= threads x efficiency."
        )


# ---------------------------------------------------------------------------
# Main.
# ---------------------------------------------------------------------------


def _ints(s: str) -> list[int]:
    try:
        out = [int(float(x)) for x in s.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {s!r}") from None
    if not out or min(out) < 1:
        raise argparse.ArgumentTypeError(f"expected positive integers, got {s!r}")
    return out


def write_json(path: Path, doc: dict[str, Any]) -> None:
    """Strict JSON, written to a temporary name then renamed."""
    text = json.dumps(doc, indent=2, allow_nan=False)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text + "\n", encoding="utf-8")
    os.replace(tmp, path)


def _in_fresh_process(workload: str, n: int, args: argparse.Namespace) -> list[dict[str, Any]]:
    """Runs one rollout workload at one size in a fresh Python process (its tables
    are printed there); returns its tables as JSON dicts."""
    import subprocess
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "w.json"
        cmd = [
            sys.executable, str(Path(__file__).resolve()), "--same-process", "--only",
            workload, f"--{workload}-samples", str(n), "--followers", str(args.followers),
            "--repeat", str(args.repeat), "--seconds", str(args.seconds), "--allocator",
            args.allocator, "--json", str(out),
        ]  # fmt: skip
        sys.stdout.flush()
        rc = subprocess.run(cmd, check=False).returncode
        if rc == 1:
            raise PeerMismatch(f"{workload} at {n:,} samples: see above")
        if rc != 0:
            raise KeyboardInterrupt if rc == 130 else RuntimeError(f"{workload}: exit {rc}")
        doc = json.loads(out.read_text())
    return list(doc["workloads"])


def main(argv: Sequence[str] | None = None) -> int:
    """Runs the selected workloads, prints one table each; returns the exit code."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--open-samples", type=_ints, default=[100_000, 1_000_000])
    ap.add_argument("--closed-samples", type=_ints, default=[100_000, 1_000_000])
    ap.add_argument("--platoon-samples", type=_ints, default=[6_000, 100_000])
    ap.add_argument("--followers", type=int, default=20)
    ap.add_argument("--cost-params", type=int, default=10_000, help="sets x one run")
    ap.add_argument("--cost-runs-params", type=int, default=1_000, help="sets x the 10 runs")
    ap.add_argument("--threads", type=_ints, default=[1, 2], help="for the batched cost")
    ap.add_argument(
        "--repeat", type=int, default=10,
        help="timed calls (best kept; round-robin, so load bursts hit all alike)",
    )  # fmt: skip
    ap.add_argument(
        "--seconds", type=float, default=1.0,
        help="and keep calling until each implementation ran this long (best kept)",
    )  # fmt: skip
    ap.add_argument("--quick", action="store_true", help="small sizes, 2 repeats")
    ap.add_argument("--only", default="open,closed,platoon,cost", help="workloads to run")
    ap.add_argument("--json", type=Path, default=None, help="write the tables here")
    ap.add_argument(
        "--same-process", action="store_true",
        help="run the rollout workloads in this process (by default each (workload, "
        "size) runs in a fresh process, so that glibc's adaptive thresholds, which "
        "earlier allocations raise, do not carry from one workload to the next)",
    )  # fmt: skip
    ap.add_argument(
        "--allocator", choices=["keep", "default"], default="default",
        help="default (the default): the allocator as every user runs it; keep: glibc "
        "keeps freed memory (mallopt), so that no implementation's fresh outputs "
        "page-fault (timings then measure the stepping alone)",
    )  # fmt: skip
    args = ap.parse_args(argv)
    if args.quick:
        args.open_samples, args.closed_samples = [20_000], [20_000]
        args.platoon_samples, args.cost_params, args.cost_runs_params = [2_000], 500, 50
        args.repeat, args.seconds = 2, 0.0
    if args.followers < 1:
        ap.error("--followers must be >= 1")
    only = {w.strip() for w in args.only.split(",") if w.strip()}
    unknown = only - {"open", "closed", "platoon", "cost"}
    if unknown:
        ap.error(f"--only: unknown workloads {sorted(unknown)}")

    import numba

    alloc = keep_freed_memory() if args.allocator == "keep" else "allocator left as it is"
    load0 = os.getloadavg()
    meta = {
        "avll": avll.__version__,
        "numba": numba.__version__,
        "numpy": np.__version__,
        "python": platform.python_version(),
        "machine": platform.machine(),
        "cpus": os.cpu_count(),
        "numba_threading_layer_config": numba.config.THREADING_LAYER,
        "load_average_start": list(load0),
        "repeat": args.repeat,
        "seconds": args.seconds,
        "dt": DT,
        "model": MODEL.to_dict(),
        "tolerance": TOL,
        "allocator": alloc,
        "isolation": "one process for all workloads" if args.same_process else
        "each rollout workload and size in a fresh process",
    }
    print(
        f"avll {avll.__version__}, numba {numba.__version__}, numpy {np.__version__}; "
        f"{platform.machine()}, {os.cpu_count()} CPUs; load average {load0[0]:.2f} at start"
    )
    print(
        "Rates are M model-steps/s per core (work / best process CPU time); on a shared "
        "machine they are noisy: compare ratios from one run."
    )
    print(f"Allocator: {alloc}; 'faults' is minor page faults per timed call.")
    tables: list[Table] = []
    scalings: list[dict[str, Any]] = []
    interrupted = False
    isolated: list[dict[str, Any]] = []
    try:
        rollouts = [
            (w, n)
            for w, sizes in (("open", args.open_samples), ("closed", args.closed_samples),
                             ("platoon", args.platoon_samples))
            if w in only
            for n in sizes
        ]
        for w, n in rollouts:
            if args.same_process:
                if w == "open":
                    ts = bench_open(n, args.repeat, args.seconds)
                elif w == "closed":
                    ts = bench_closed(n, args.repeat, args.seconds)
                else:
                    ts = bench_platoon(n, args.followers, args.repeat, args.seconds)
                for t in ts:
                    tables.append(t)
                    print_table(t)
            else:
                isolated += _in_fresh_process(w, n, args)
        if "cost" in only:
            runs = paper_experiment(seed=0, runs=PAPER_CAL_RUNS, duration=300.0)
            for n_params, rs, key, label in (
                (args.cost_params, runs[:1], "1run", f"1 run of {len(runs[0]):,} samples"),
                (
                    args.cost_runs_params,
                    runs,
                    f"{len(runs)}runs",
                    f"the paper's {len(runs)} runs of {len(runs[0]):,} samples",
                ),
            ):
                threads = sorted(set(args.threads))
                ts, sc = bench_cost(n_params, rs, key, label, args.repeat, threads, args.seconds)
                for t in ts:
                    tables.append(t)
                    print_table(t)
                if len(sc["threads"]) == 2 and sc["threads"][0] != sc["threads"][1]:
                    scalings.append(sc)
                    print_scaling(sc)
    except PeerMismatch as e:
        print(f"\nbench_engine: a peer does not match avll, nothing more timed: {e}")
        return 1
    except KeyboardInterrupt:
        interrupted = True
        print("\ninterrupted: the tables above are complete, the rest was not run")
    meta["load_average_end"] = list(os.getloadavg())
    print(f"\nload average at end: {meta['load_average_end'][0]:.2f}")
    if args.json is not None:
        doc = {
            "meta": meta,
            "interrupted": interrupted,
            "workloads": isolated + [t.to_json() for t in tables],
            "scaling": scalings,
        }
        write_json(args.json, doc)
        print(f"wrote {args.json}")
    return 130 if interrupted else 0


if __name__ == "__main__":
    sys.exit(main())
