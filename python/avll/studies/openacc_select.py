"""Cross-validated selection of the structures a car's follower carries (the OpenACC
study's structure stage, :func:`select_structures`).

**Candidates.** They grow from the lower level to the whole follower: the lower-level
effects that act in closed loop and have a small-signal form (``delay``: a command
delay outside the inner loop) and the upper-level structures commercial ACCs are known
or suspected to have (``perception``: a radar delay, ``feedforward``: a
predecessor-acceleration feedforward, ``closing``: other gains when closing in,
``speed_gains``: speed-dependent gains and time gap); :data:`CANDIDATES`.

**Folds.** The out-of-sample step's folds (leave one file out): per car and setting
(campaign, car, setting, ACC state: :func:`avll.studies.openacc._oos_key`) each file
is held out in turn and the model is calibrated on the car's other files of that
setting. Grouping per car *and setting* (not per car model pooled over settings): the
setting changes the ACC's time gap, and the calibration has one upper law per problem
(no setting-specific ``Tg`` within one fit), so pooling settings would bias the shared
fit; the folds are then the ones the out-of-sample predictions already use.

**Step.** For every group's current structures ``S`` (first: none, the base fits of
the out-of-sample step) and every candidate ``c`` not in ``S``, the folds of the groups
at ``S`` are calibrated with ``S + c`` in ONE :func:`avll.calibrate` call with
``subsets`` (one problem per fold), each problem warm-started from its current fit
with ``c`` at its neutral values (:func:`avll.calibration.start_row`): with elitism a
richer fit never ends above the fit it contains. The **control** is ``S`` itself
searched again from the same starts with the same budget (one more call): a GA that
has not converged would otherwise credit a candidate with the extra search it gets.
Each fold's held-out file is then simulated in closed loop (the study's objective,
weights ``weights``: per sample ``e² = wa ea² + wv ev² + wx ex²``) under the control
and the candidate fit. A candidate is
**accepted** for a group when (a) the held-out error falls by at least ``min_gain``
(relative) in most of the group's folds (more than half), and (b) the pooled gain is at
least ``min_gain`` and significant: a moving-block bootstrap of the held-out loss
difference (:func:`avll.diagnose.stats.block_bootstrap_gain`, blocks from the loss
difference's own autocorrelation, so serial correlation is respected) gives a one-sided
p-value below ``alpha``. Of the accepted candidates the one with the largest pooled
gain joins the group's structures; this repeats (greedy) up to ``max_structures``.

The final fits of each fold (``fold_fits``) are those of the group's accepted
structures; the study predicts with them (``amplification_predicted_oos``) and
re-fits each run in-sample with them (``amplification_predicted``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..data import Run
from ..report import finite_or_none as _fin

__all__ = ["CANDIDATES", "MIN_GAIN", "ALPHA", "MAX_STRUCTURES", "StructureStep",
           "StructureSelection", "heldout_loss", "select_structures"]

#: Candidate structures, from the lower level to the whole follower.
CANDIDATES: tuple[str, ...] = ("delay", "perception", "feedforward", "closing", "speed_gains")
#: Minimum relative reduction of the held-out error (per fold and pooled).
MIN_GAIN: float = 0.02
#: One-sided significance level of the pooled gain.
ALPHA: float = 0.05
#: Structures accepted at most per group.
MAX_STRUCTURES: int = 2
#: Replicates of the block bootstrap of each test.
N_BOOT: int = 1000


@dataclass(frozen=True)
class StructureStep:
    """One candidate tried for one group: the group (``campaign``, ``car``,
    ``setting``), the structures it had (``before``), the ``candidate``, the held-out
    files (``files``) and their relative gains ``fold_gains`` (``1 - mse_after /
    mse_before``), the pooled ``gain``, its bootstrap ``p_value`` and interval
    ``ci``, whether it passed both rules (``passes``) and whether it was the one
    ``accepted`` in that round."""

    campaign: str | None
    car: str | None
    setting: Any
    before: tuple[str, ...]
    candidate: str
    files: tuple[str, ...]
    fold_gains: tuple[float, ...]
    gain: float
    p_value: float
    ci: tuple[float, float]
    passes: bool
    accepted: bool

    def to_dict(self) -> dict[str, Any]:
        """Strict-JSON-ready fields (non-finite numbers as None)."""
        return {"campaign": self.campaign, "car": self.car, "setting": self.setting,
                "before": list(self.before), "candidate": self.candidate,
                "files": list(self.files), "fold_gains": [_fin(g) for g in self.fold_gains],
                "gain": _fin(self.gain), "p_value": _fin(self.p_value),
                "ci": [_fin(self.ci[0]), _fin(self.ci[1])], "passes": self.passes,
                "accepted": self.accepted}


@dataclass(frozen=True)
class StructureSelection:
    """Result of :func:`select_structures`: per fold problem ``k`` (the out-of-sample
    plan's subsets) the accepted structures ``effects[k]`` (canonical order) and the
    final fit ``fold_fits[k]`` (base fits where nothing was accepted), every step
    tried (``steps``), the settings, the number of calibration problems solved
    (``problems``) and the wall time (``seconds``)."""

    effects: tuple[tuple[str, ...], ...]
    fold_fits: tuple[Any, ...]
    steps: tuple[StructureStep, ...]
    candidates: tuple[str, ...]
    min_gain: float
    alpha: float
    max_structures: int
    problems: int
    calls: int
    seconds: float

    def to_dict(self) -> dict[str, Any]:
        """Strict-JSON-ready summary (the fits left out)."""
        return {"candidates": list(self.candidates), "min_gain": self.min_gain,
                "alpha": self.alpha, "max_structures": self.max_structures,
                "grouping": "per car and setting (the out-of-sample folds: leave one file "
                            "out)",
                "test": "moving-block bootstrap of the held-out loss difference "
                        "(avll.diagnose.stats.block_bootstrap_gain), one-sided",
                "problems": self.problems, "calls": self.calls,
                "seconds": round(self.seconds, 1),
                "steps": [s.to_dict() for s in self.steps]}


def heldout_loss(model: str, fit: Any, effects: Sequence[str], run: Run,
                 weights: tuple[float, float, float], threads: int = 0) -> np.ndarray:
    """Per-sample held-out error ``sqrt(wa ea² + wv ev² + wx ex²)`` of the closed-loop
    fit ``fit`` (its row ``[model | effects | kg, kv, Tg, Gmin]``) replayed on ``run``
    from rest, exactly as the calibration's cost sees it (its mean square is the run's
    cost); ``inf`` where the replay diverges."""
    from ..rollout import simulate_batch

    assert run.x is not None and run.v is not None
    row = np.asarray(fit.x, dtype=np.float64)[None, :]
    sim = simulate_batch(model, row, [run], effects=list(effects), weights=weights,
                         init="rest", closed_loop=True, upper_free=[0, 1, 2, 3],
                         threads=threads)  # fmt: skip
    wa, wv, wx = weights
    e2 = (wa * (sim.a[0][0] - run.a) ** 2 + wv * (sim.v[0][0] - run.v) ** 2
          + wx * (sim.x[0][0] - run.x) ** 2)
    return np.asarray(np.where(np.isfinite(e2), np.sqrt(np.abs(e2)), np.inf))


def select_structures(
    model: str,
    runs: Sequence[Run],
    plan: Mapping[str, Any],
    base_fits: Sequence[Any],
    groups: Sequence[Any],
    *,
    calibrate_kw: Mapping[str, Any],
    weights: tuple[float, float, float],
    candidates: Sequence[str] = CANDIDATES,
    min_gain: float = MIN_GAIN,
    alpha: float = ALPHA,
    max_structures: int = MAX_STRUCTURES,
    seed: int = 0,
    threads: int = 0,
    log: Callable[[str], Any] | None = None,
) -> StructureSelection:
    """The cross-validated structure selection (see the module doc).

    ``plan`` is the out-of-sample plan (:func:`avll.studies.openacc._oos_plan`:
    ``subsets``, ``problem`` per run), ``base_fits`` the base model's fit per subset,
    ``groups`` each run's group key (None: no group), ``calibrate_kw`` the study's
    calibration options (closed loop, bounds, weights, GA budget; ``starts`` is 1 here:
    every problem starts from its current fit). Deterministic in ``seed``."""
    from ..calibration import calibrate, start_row
    from ..diagnose.stats import block_bootstrap_gain
    from ..effects import EFFECTS, canonical

    say = log or (lambda s: None)
    t0 = time.perf_counter()
    for c in candidates:
        if c not in EFFECTS:
            raise ValueError(f"candidates: unknown structure {c!r}; known: {', '.join(EFFECTS)}")
    if not (0.0 <= float(min_gain) < 1.0):
        raise ValueError(f"min_gain: must be in [0, 1), got {min_gain!r}")
    if not (0.0 < float(alpha) < 1.0):
        raise ValueError(f"alpha: must be in (0, 1), got {alpha!r}")
    if isinstance(max_structures, bool) or int(max_structures) < 0:
        raise ValueError(f"max_structures: must be an integer >= 0, got {max_structures!r}")
    subsets = plan["subsets"]
    n_prob = len(subsets)
    # held-out runs of each problem, and each group's problems
    held: list[list[int]] = [[] for _ in range(n_prob)]
    for i, k in enumerate(plan["problem"]):
        if k is not None:
            held[k].append(i)
    group_of: list[Any] = [groups[held[k][0]] for k in range(n_prob)]
    gkeys = list(dict.fromkeys(g for g in group_of if g is not None))
    probs_of = {g: [k for k in range(n_prob) if group_of[k] == g] for g in gkeys}
    fits: list[Any] = list(base_fits)
    effs: list[tuple[str, ...]] = [() for _ in range(n_prob)]
    loss: dict[int, np.ndarray] = {}
    for k in range(n_prob):
        for i in held[k]:
            loss[i] = heldout_loss(model, fits[k], (), runs[i], weights, threads)
    active = {g: True for g in gkeys}
    steps: list[StructureStep] = []
    n_problems = calls = 0

    def folds(effects: Sequence[str], ks: list[int], starts: list[list[Any]], seed_k: int
              ) -> list[Any]:
        """One calibration of the folds ``ks`` with ``effects`` from ``starts``."""
        nonlocal n_problems, calls
        res = calibrate(model, runs, effects=list(effects), subsets=[subsets[k] for k in ks],
                        initial_per_problem=starts, seed=seed_k, threads=threads, starts=1,
                        **calibrate_kw)  # fmt: skip
        calls += 1
        n_problems += len(ks)
        if any(r.interrupted for r in res):
            raise KeyboardInterrupt
        return res

    for rnd in range(int(max_structures)):
        by_set: dict[tuple[str, ...], list[Any]] = {}
        for g in gkeys:
            if active[g]:
                by_set.setdefault(effs[probs_of[g][0]], []).append(g)
        if not by_set:
            break
        # every (set, candidate): one calibration of the folds of the groups at that set
        tried: dict[Any, list[tuple[str, tuple[str, ...], list[Any], dict[int, np.ndarray],
                                    StructureStep]]] = {g: [] for gs in by_set.values()
                                                        for g in gs}
        for cur, gs in by_set.items():
            ks = [k for g in gs for k in probs_of[g]]
            # the control: the current structures searched again from the same starts
            # with the same budget, so that a candidate wins by its structure, not by
            # the extra search it gets
            say(f"structures, round {rnd + 1}: {'+'.join(cur) or 'base'} (control) on "
                f"{len(ks)} folds")
            ctrl = folds(cur, ks, [[fits[k].x] for k in ks],
                         int(seed) + 104729 * (rnd + 1) + 7 * len(candidates))
            for k, f in zip(ks, ctrl, strict=True):
                for i in held[k]:
                    loss[i] = heldout_loss(model, f, cur, runs[i], weights, threads)
            for c in candidates:
                if c in cur:
                    continue
                try:
                    new = canonical([*cur, c])
                except ValueError:
                    continue
                say(f"structures, round {rnd + 1}: {'+'.join(cur) or 'base'} + {c} on "
                    f"{len(ks)} folds ({len(gs)} car-settings)")
                res = folds(new, ks, [[start_row(fits[k], [c])] for k in ks],
                            int(seed) + 104729 * (rnd + 1) + 7 * list(candidates).index(c))
                fk = dict(zip(ks, res, strict=True))
                for g in gs:
                    before, after, gains, files = [], [], [], []
                    new_loss: dict[int, np.ndarray] = {}
                    for k in probs_of[g]:
                        for i in held[k]:
                            la = heldout_loss(model, fk[k], new, runs[i], weights, threads)
                            new_loss[i] = la
                            before.append(loss[i])
                            after.append(la)
                            m0, m1 = float(np.mean(loss[i] ** 2)), float(np.mean(la ** 2))
                            gains.append(1.0 - m1 / m0 if m0 > 0 else -math.inf)
                            files.append(str(runs[i].meta.get("file") or runs[i].run_id))
                    bt = block_bootstrap_gain(before, after, n_boot=N_BOOT,
                                              seed=int(seed) + len(steps))
                    most = sum(x >= min_gain for x in gains) > len(gains) / 2
                    ok = bool(most and bt.gain >= min_gain and bt.p_value < alpha)
                    c0, s0, a0 = (g[0], g[1], g[2]) if isinstance(g, tuple) else (None, g, None)
                    st = StructureStep(c0, s0, a0, cur, c, tuple(files), tuple(gains),
                                       float(bt.gain), float(bt.p_value),
                                       (float(bt.ci[0]), float(bt.ci[1])), ok, False)
                    tried[g].append((c, new, [fk[k] for k in probs_of[g]], new_loss, st))
        for g, opts in tried.items():
            best = max((o for o in opts if o[4].passes), key=lambda o: o[4].gain, default=None)
            for o in opts:
                acc = best is not None and o is best
                steps.append(replace(o[4], accepted=True) if acc else o[4])
            if best is None:
                active[g] = False
                continue
            _, new, new_fits, new_loss, _ = best
            for k, f in zip(probs_of[g], new_fits, strict=True):
                fits[k] = f
                effs[k] = new
            loss.update(new_loss)
    return StructureSelection(tuple(effs), tuple(fits), tuple(steps), tuple(candidates),
                              float(min_gain), float(alpha), int(max_structures), n_problems,
                              calls, time.perf_counter() - t0)
