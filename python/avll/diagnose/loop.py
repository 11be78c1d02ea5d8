"""The add-effect loop with cross-validated selection.

Three disjoint sets of runs:

* **calibration runs** fit every model and decide which effect is accepted, by
  cross-validation over runs inside them;
* **validation runs** (optional) are only reported: they decide nothing;
* **test runs** (optional) are simulated only after the loop has finished; a gain
  that does not hold there is flagged.

Folds. With ``n >= 2`` calibration runs, ``k = min(folds, n)`` folds of whole runs
(``folds`` defaults to 5): leave-one-run-out when ``k = n``, otherwise the runs
shuffled by ``seed`` and cut into ``k`` groups. With a single calibration run, the
run is cut into ``k`` contiguous blocks of equal length (``folds`` defaults to 3),
each block a held-out fold and a run of its own (it starts from its first measured
speed and position); neighbouring blocks are correlated, so block folds are
weaker evidence than folds of separate runs (the JSON says which were used).

One iteration: diagnose the current model on all calibration runs (the score test
of :mod:`avll.diagnose.signatures` only *ranks* effects); for each of the ``tries``
best-ranked effects and each fold, fit the current model and the model with the
effect on the fold's training runs (the one calibration entry, :func:`avll.calibrate`,
seeded per fold; the effect's starting guess
comes from a diagnosis on the training runs only) and compare their squared errors
on the held-out fold. An effect is **accepted** only if all of:

1. it lowers the held-out error by at least ``min_gain`` (relative MSE reduction,
   default 5 %) in most folds: ``fold_selection`` — the share of folds where it does
   — is above one half;
2. the pooled out-of-fold relative MSE reduction is at least ``min_gain`` (a
   "significant" gain below the minimum effect size is not accepted);
3. the pooled per-sample loss difference ``e_before² - e_after²`` is positive by a
   one-sided t-test with the effective sample size of that difference
   (:func:`avll.diagnose.stats.loss_difference_test`), ``p < alpha``;
4. refitted on all calibration runs, it lowers their error.

Of the effects that pass, the one with the largest pooled out-of-fold gain is added
(a moving-block bootstrap interval of that gain is reported beside it); the loop
repeats until nothing passes or ``max_effects`` are in. Afterwards the residual is
checked for structure no effect explains (:func:`avll.diagnose.signatures.residual_structure`):
an honest "none of these" instead of the least-bad effect.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, is_dataclass, replace
from typing import Any

import numpy as np

from .. import _core
from .._limits import check_int, check_number, check_seed, check_threads
from ..calibration import _average as _mean
from ..calibration import calibrate
from ..data import DataWarning, Run
from ..defaults import DEFAULT_STARTS, GA_OPTIONS, UPPER_PLACEHOLDER
from ..effects import EFFECTS, WithEffects
from ..models import LowerLevelModel, UpperLevel, model_class
from ..progress import Progress, messages
from ..runs import RunSet
from .contract import model_to_dict
from .defaults import (
    ALPHA,
    DEFAULT_BLOCKS,
    DEFAULT_FOLDS,
    FAR_SMALLER,
    MAX_EFFECTS,
    MIN_BLOCK,
    MIN_GAIN,
    MIN_SHARE,
    N_BOOT,
)
from .fitting import AtBound, at_bound, calibrate_kw, run_mse, simulate_runs
from .signatures import Diagnosis, diagnose, not_offered, residual_structure
from .stats import BootstrapGain, LossTest, block_bootstrap_gain, loss_difference_test

__all__ = ["MIN_GAIN", "Trial", "Flag", "Splits", "Selection", "Step", "LoopResult",
           "effect_loop", "make_folds"]


def _gain(before: dict[str, float] | None, after: dict[str, float] | None) -> float:
    b, a = _mean(before), _mean(after)
    return 1.0 - a / b if b > 0 and math.isfinite(b) else float("nan")


@dataclass(frozen=True)
class Trial:
    """One effect cross-validated in one iteration: the share of folds in which it
    lowers the held-out error by ``min_gain`` (``fold_selection``), the gain per fold,
    the pooled out-of-fold loss test (``test``) and block bootstrap (``boot``), the
    folds (how many, of which kind) and why it was rejected (``reasons``; none: it
    passed)."""

    iteration: int
    effect: str
    fold_selection: float
    fold_gains: tuple[float, ...]
    test: LossTest
    boot: BootstrapGain
    folds: int
    fold_kind: str
    reasons: tuple[str, ...] = ()

    @property
    def passed(self) -> bool:
        """Whether every rule of the module doc held."""
        return not self.reasons

    @property
    def gain(self) -> float:
        """The pooled out-of-fold relative MSE reduction."""
        return self.boot.gain

    @property
    def p_value(self) -> float:
        """The block-bootstrap p-value of "no reduction"."""
        return self.boot.p_value

    def cv_dict(self) -> dict[str, Any]:
        """The cross-validation record (``cv`` of a step in the JSON)."""
        t, b = self.test, self.boot
        d: dict[str, Any] = {
            "fold_gains": list(self.fold_gains), "gain": b.gain, "mse_before": t.mse_before,
            "mse_after": t.mse_after, "p_value": b.p_value, "bootstrap_ci": list(b.ci),
            "block_length": b.block_length, "n_boot": b.n_boot, "ess_t": t.t,
            "ess_t_p_value": t.p_value, "n": t.n, "n_eff": t.n_eff}  # fmt: skip
        if not all(math.isfinite(g) for g in self.fold_gains):
            d["fold_gains_note"] = "null: a model's simulation is not finite on that held-out fold"
        if not all(math.isfinite(x) for x in b.ci):
            d["bootstrap_ci_note"] = "null: no finite bootstrap of the loss difference"
        return d

    def to_dict(self) -> dict[str, Any]:
        """A JSON-able dict (an entry of ``trials`` in the ``avll diagnose`` JSON)."""
        return {"iteration": self.iteration, "effect": self.effect,
                "fold_selection": self.fold_selection, **self.cv_dict(), "passed": self.passed,
                "reasons": list(self.reasons)}  # fmt: skip

    def rejection(self) -> dict[str, Any]:
        """A JSON-able dict (an entry of ``rejected``)."""
        return {"iteration": self.iteration, "effect": self.effect,
                "fold_selection": self.fold_selection, "gain": self.gain,
                "p_value": self.p_value, "reasons": list(self.reasons)}  # fmt: skip


@dataclass(frozen=True)
class Flag:
    """A warning on the result: its ``kind`` (``at_bound``, ``validation_gain_not_held``,
    ``validation_gain_far_smaller``, ``test_gain_not_held``, ``test_gain_far_smaller``,
    ``structure_unexplained``), the step it concerns (0 the baseline, ``None`` the whole
    loop), the effect, the parameters at a bound (``at_bound``) and a message."""

    kind: str
    step: int | None
    effect: str | None
    message: str
    params: tuple[str, ...] | None = None

    def to_dict(self) -> dict[str, Any]:
        """A JSON-able dict (an entry of ``flags``)."""
        d: dict[str, Any] = {"kind": self.kind, "step": self.step, "effect": self.effect}
        if self.params is not None:
            d["params"] = list(self.params)
        return d | {"message": self.message}


@dataclass(frozen=True)
class Splits:
    """The runs of each split (ids) and the held-out runs of each fold."""

    cal_runs: tuple[str, ...]
    val_runs: tuple[str, ...]
    test_runs: tuple[str, ...]
    folds: tuple[tuple[str, ...], ...]
    fold_kind: str


@dataclass(frozen=True)
class Selection:
    """The settings of the selection rule (``selection`` in the JSON)."""

    min_gain: float
    alpha: float
    cv_alpha: float
    n_boot: int
    folds: int
    fold_kind: str
    tries: int
    max_effects: int
    max_generations: int
    starts: int
    seed: int
    candidates: tuple[str, ...] | None
    structure_alpha: float
    min_structure: float
    far_smaller: float = FAR_SMALLER
    rule: str = "cross-validation over calibration folds"
    majority: str = "fold_selection > 0.5"


def _plain(x: Any) -> Any:
    """Dataclasses as dicts, tuples as lists (JSON-able)."""
    if is_dataclass(x) and not isinstance(x, type):
        return {k: _plain(v) for k, v in vars(x).items()}
    return [_plain(v) for v in x] if isinstance(x, (list, tuple)) else x


@dataclass(frozen=True)
class Step:
    """One accepted effect: its parameters, the errors before and after (per run) on
    the calibration, validation and test runs, its cross-validation record and the
    parameters found at a bound of the search box."""

    effect: str
    params: dict[str, float]
    model: WithEffects
    cal_before: dict[str, float]
    cal_after: dict[str, float]
    val_before: dict[str, float]
    val_after: dict[str, float]
    cv: Trial
    at_bound: tuple[AtBound, ...] = ()
    test_before: dict[str, float] = field(default_factory=dict)
    test_after: dict[str, float] = field(default_factory=dict)
    upper: UpperLevel | None = None
    flags: tuple[str, ...] = ()

    @property
    def fold_selection(self) -> float:
        """The share of folds in which the effect lowered the held-out error enough."""
        return self.cv.fold_selection

    @property
    def p_value(self) -> float:
        """The one-sided p-value of the pooled out-of-fold loss difference."""
        return self.cv.p_value

    def to_dict(self) -> dict[str, Any]:
        """A JSON-able dict (the ``avll diagnose`` JSON contract)."""
        d: dict[str, Any] = {"effect": self.effect, "params": self.params,
                             "model": self.model.name}
        for sp, b, a in (("cal", self.cal_before, self.cal_after),
                         ("val", self.val_before, self.val_after),
                         ("test", self.test_before, self.test_after)):  # fmt: skip
            if b or sp == "cal":
                d.update({f"{sp}_mse_before": _mean(b), f"{sp}_mse_after": _mean(a),
                          f"{sp}_mse_before_per_run": b, f"{sp}_mse_after_per_run": a})
            elif sp == "val":
                d.update(val_mse_before=None, val_mse_after=None,
                         val_note="no validation runs given")  # fmt: skip
        cv = self.cv.cv_dict() | {"folds": self.cv.folds, "fold_kind": self.cv.fold_kind}
        d.update(fold_selection=self.fold_selection, p_value=self.p_value, cv=cv,
                 at_bound=_plain(self.at_bound), flags=list(self.flags))  # fmt: skip
        if self.upper is not None:
            d["upper"] = asdict(self.upper)
        return d


@dataclass(frozen=True)
class LoopResult:
    """The baseline, the accepted steps, every diagnosis, every cross-validated
    candidate (``trials``; ``rejected`` those that failed), the splits, the rule's
    settings, the flags and what the residual keeps (``unexplained``, the report of
    :func:`avll.diagnose.signatures.residual_structure`)."""

    baseline: WithEffects
    final: WithEffects
    steps: list[Step]
    diagnoses: list[Diagnosis]
    rejected: list[Trial]
    upper: UpperLevel | None
    trials: list[Trial]
    splits: Splits
    settings: Selection
    baseline_mse: dict[str, dict[str, float]] = field(default_factory=dict)
    baseline_at_bound: tuple[AtBound, ...] = ()
    baseline_upper: UpperLevel | None = None
    unexplained: dict[str, Any] = field(default_factory=dict)
    flags: list[Flag] = field(default_factory=list)
    init: str = "rest"
    closed_loop: bool = False

    @property
    def final_model(self) -> dict[str, Any]:
        """The final model as the ``final_model`` dict (:func:`avll.model_from_dict`)."""
        return model_to_dict(self.final, upper=self.upper, init=self.init,
                             closed_loop=self.closed_loop)  # fmt: skip

    def plot(self) -> Any:
        """The final residual against speed, time and command, what the accepted
        effects leave unexplained (:func:`avll.plotting.residual_unexplained`)."""
        from ..plotting import residual_unexplained

        return residual_unexplained(self.unexplained)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-able dict (the ``avll diagnose`` JSON contract; non-finite numbers
        are left to :func:`avll._atomic.json_safe`, which writes ``null`` with a note)."""
        return {
            "upper": None if self.upper is None else asdict(self.upper),
            "base_model": self.baseline.base.name,
            "baseline_params": self.baseline.base.to_dict(),
            "baseline_mse": {k: {"mean": _mean(v), "per_run": v} if v else
                             {"mean": None, "mean_note": "no runs in this split", "per_run": {}}
                             for k, v in self.baseline_mse.items()},
            "baseline_at_bound": _plain(self.baseline_at_bound),
            "steps": [s.to_dict() for s in self.steps],
            "effects": [s.effect for s in self.steps],
            "final_params": {e.name: e.to_dict() for e in self.final.effects}
            | {"base": self.final.base.to_dict()},
            "final_model": self.final_model,
            "splits": _plain(self.splits),
            "selection": _plain(self.settings),
            "trials": [t.to_dict() for t in self.trials],
            "rejected": [t.rejection() for t in self.rejected],
            "unexplained": self.unexplained,
            "flags": [f.to_dict() for f in self.flags],
            "diagnoses": [d.to_dict() for d in self.diagnoses],
        }  # fmt: skip


# ---------------------------------------------------------------------------
# Folds
# ---------------------------------------------------------------------------


def make_folds(
    runs: Sequence[Run], folds: int | None = None, seed: int = 0
) -> tuple[list[tuple[list[Run], list[Run]]], str]:
    """The cross-validation folds of the calibration runs as ``[(train, held_out)]``
    and their kind, ``"runs"`` or ``"blocks"`` (see the module doc). Deterministic
    from ``seed``."""
    runs = list(runs)
    if not runs:
        raise ValueError("cal_runs: no calibration runs")
    if len(runs) == 1:
        k = DEFAULT_BLOCKS if folds is None else check_int(folds, "folds", min=2)
        r = runs[0]
        n = len(r)
        if n // k < MIN_BLOCK:
            raise ValueError(
                f"folds: a single calibration run ({r.run_id!r}, {n} samples) cut into {k} "
                f"blocks gives blocks shorter than {MIN_BLOCK} samples; give more "
                "calibration runs or fewer folds")
        edges = np.linspace(0, n, k + 1).round().astype(int)
        blocks = [r.cut(int(a), int(b), f"[{a}:{b}]") for a, b in zip(edges[:-1], edges[1:],
                                                                  strict=True)]
        return [([b for j, b in enumerate(blocks) if j != i], [blocks[i]])
                for i in range(k)], "blocks"  # fmt: skip
    k = min(DEFAULT_FOLDS if folds is None else check_int(folds, "folds", min=2), len(runs))
    if k == len(runs):
        groups = [[i] for i in range(k)]
    else:
        perm = np.random.default_rng([int(seed) % 2**63, 13]).permutation(len(runs))
        groups = [sorted(int(i) for i in g) for g in np.array_split(perm, k)]
    return [([r for i, r in enumerate(runs) if i not in g], [runs[i] for i in g])
            for g in groups], "runs"  # fmt: skip


def _sub(seed: int, *ks: int) -> int:
    s = int(seed)
    for k in ks:
        s = int(_core.derive_seed(s, int(k)))
    return s


# ---------------------------------------------------------------------------
# The loop
# ---------------------------------------------------------------------------


def effect_loop(
    base: str | type[LowerLevelModel],
    cal_runs: Sequence[Run],
    val_runs: Sequence[Run] = (),
    *,
    test_runs: Sequence[Run] = (),
    seed: int = 0,
    closed_loop: bool | None = None,
    alpha: float = ALPHA,
    cv_alpha: float = 0.01,
    min_gain: float = MIN_GAIN,
    folds: int | None = None,
    max_effects: int = MAX_EFFECTS,
    tries: int = 2,
    baseline: LowerLevelModel | None = None,
    candidates: Sequence[str] | None = None,
    init: str = "auto",
    max_generations: int | None = None,
    starts: int = DEFAULT_STARTS,
    structure_alpha: float = ALPHA,
    min_structure: float = MIN_SHARE,
    n_boot: int = N_BOOT,
    threads: int = 0,
    progress: Any = False,
) -> LoopResult:
    """Baseline fit -> diagnose -> cross-validate the ``tries`` best-ranked effects
    over folds of the calibration runs -> add the best one that passes the rule of
    the module doc -> repeat; then report the validation and test runs and what the
    residual still depends on.

    ``val_runs`` (positional, optional) and ``test_runs`` are only reported.
    ``min_gain``: minimum relative MSE reduction (default :data:`MIN_GAIN`);
    ``alpha``: level of the diagnosis' screening and of the out-of-fold loss test;
    ``folds``: number of folds (default ``min(5, n)`` runs, 3 blocks of a single run);
    ``max_generations``/``starts``: the GA budget of every fit; ``candidates``: the effects
    offered (default: every registered effect that applies);
    ``structure_alpha``/``min_structure``: when the final residual "keeps structure"
    (:func:`avll.diagnose.signatures.residual_structure`); ``progress``: ``True``,
    ``False`` or a mode of :mod:`avll.progress` (a stage per fit, step messages on
    stderr)."""
    max_effects = check_int(max_effects, "max_effects", min=0, max=len(EFFECTS))
    tries = check_int(tries, "tries", min=1)
    seed = check_seed(seed)
    threads = check_threads(threads)
    max_generations = check_int(GA_OPTIONS["max_generations"] if max_generations is None
                                else max_generations, "max_generations", min=1)
    n_boot = check_int(n_boot, "n_boot", min=10)
    min_gain = check_number(min_gain, "min_gain")
    if not 0 <= min_gain < 1:
        raise ValueError(f"min_gain: must be in [0, 1), got {min_gain}")
    for nm, val in (("alpha", alpha), ("cv_alpha", cv_alpha)):
        if not 0 < check_number(val, nm) < 1:
            raise ValueError(f"{nm}: must be in (0, 1), got {val}")
    cal_runs, val_runs, test_runs = list(cal_runs), list(val_runs), list(test_runs)
    if not cal_runs:
        raise ValueError("cal_runs: no calibration runs")
    ids = {"cal_runs": [r.run_id for r in cal_runs], "val_runs": [r.run_id for r in val_runs],
           "test_runs": [r.run_id for r in test_runs]}  # fmt: skip
    seen: dict[str, str] = {}
    for name, lst in ids.items():
        for i in lst:
            if i in seen:
                raise ValueError(f"{name}: run {i!r} is also in {seen[i]}; the splits must be "
                                 "disjoint")  # fmt: skip
            seen[i] = name
    # The loop's settings of every fit (avll.calibrate's keywords) and simulation.
    fit_kw = calibrate_kw([*cal_runs, *val_runs, *test_runs], closed_loop, init)
    closed, init, upper_free = fit_kw["closed_loop"], fit_kw["init"], bool(fit_kw["upper_free"])
    if candidates is not None:  # one the data can never test is said, not silently dropped
        for n, why in not_offered((), [*cal_runs, *val_runs], candidates,
                                  closed=closed).items():
            warnings.warn(DataWarning(f"candidates: {n!r} is not tried: {why}"), stacklevel=2)
    bname = model_class(base).name
    kind = cal_runs[0].command_kind
    fold_sets, fold_kind = make_folds(cal_runs, folds, seed)
    say = messages("avll: diagnose", progress)
    # Every run of the loop packed once: the calibration runs (and the blocks of a
    # single one), the validation and the test runs; each split and each fold's
    # training and held-out runs are views on it (index subsets, nothing copied).
    blocks = [held[0] for _, held in fold_sets] if fold_kind == "blocks" else []
    packed = RunSet([*cal_runs, *blocks, *val_runs, *test_runs])
    where = {id(r): i for i, r in enumerate(packed)}

    def view(rs: Sequence[Run]) -> RunSet | tuple[()]:
        return packed.subset([where[id(r)] for r in rs]) if rs else ()

    cal_set, val_set, test_set = view(cal_runs), view(val_runs), view(test_runs)
    fold_views = [(view(train), view(held)) for train, held in fold_sets]

    def fit(names: Sequence[str], rs: Any, seed: int, start: WithEffects | None = None,
            start_upper: UpperLevel | None = None, show: Any = False,
            ) -> tuple[WithEffects, UpperLevel | None]:
        # The one calibration entry, with the loop's settings; ``start`` (and the law
        # ``start_upper``) joins the first population.
        initial = None
        if start is not None:
            up = start_upper or UPPER_PLACEHOLDER
            initial = [np.concatenate([start.to_array(), *([up.to_array()] if upper_free
                                                             else [])])]  # fmt: skip
        # One progress stage per fit, over the GA's generations.
        bar = Progress(max_generations, "fit " + "+".join([bname, *names]), unit="gen",
                       mode=show)  # fmt: skip
        done = False
        try:
            res = calibrate(bname, rs, effects=names, initial=initial, seed=seed,
                            starts=starts, threads=threads, max_generations=max_generations,
                            progress=(lambda i: bar.advance_to(float(i["iteration"])))
                            if bar.mode != "none" else False, **fit_kw)  # fmt: skip
            done = not res.interrupted
        finally:
            bar.close(complete=done)
        if not done:
            # A fit of the loop stopped by Ctrl-C is not a result to go on with: the
            # loop stops (nothing is written).
            raise KeyboardInterrupt
        m = res.with_effects or WithEffects(res.model, ())
        return m, UpperLevel(**res.upper) if upper_free else None

    def with_upper(rs: RunSet | tuple[()], up: UpperLevel | None) -> Any:
        # The calibrated upper-level law replaces the unknown one (on every run: the
        # same vehicle's law), as free gains of the simulated row.
        return rs.with_upper(up) if upper_free and isinstance(rs, RunSet) else rs

    def residuals(m: WithEffects, rs: Any, up: UpperLevel | None) -> list[np.ndarray]:
        rs = with_upper(rs, up)
        return [r.a - s for r, s in zip(rs, simulate_runs(m, rs, closed_loop=closed,
                                                           init=init), strict=True)]

    def mse(m: WithEffects, rs: Any, up: UpperLevel | None) -> dict[str, float]:
        # {run_id: mean((a - simulate_run(model, run))**2)}, inf when not finite
        if not rs:
            return {}
        c = run_mse(m, with_upper(rs, up), closed_loop=closed, init=init)
        return {i: float(x) if np.isfinite(x) else math.inf
                for i, x in zip(rs.run_ids, c, strict=True)}  # fmt: skip

    if baseline is None:
        current, upper = fit((), cal_set, seed, show=progress)
    else:
        if upper_free:
            raise ValueError("baseline: give runs with their upper-level law in closed loop")
        current, upper = WithEffects(baseline, ()), None
    say(f"baseline {current.base}" + (f", upper {upper}" if upper is not None else ""))
    out_base, base_upper = current, upper
    # The fold models of the current effects (fitted on each fold's training runs).
    fold_models: list[tuple[WithEffects, UpperLevel | None] | None] = [None] * len(fold_sets)
    steps: list[Step] = []
    diags: list[Diagnosis] = []
    rejected: list[Trial] = []
    trials: list[Trial] = []
    for it in range(max_effects):
        cal_u = with_upper(cal_set, upper)
        d = diagnose(current, cal_u, closed_loop=closed, alpha=alpha, init=init,
                     candidates=candidates)  # fmt: skip
        diags.append(d)
        say("ranked: " + ", ".join(f"{c.effect} {c.explained:.3f} p={c.p_value:.2g}"
                                   for c in d.candidates))  # fmt: skip
        ranked = d.ranked[:tries]
        if not ranked:
            break
        for f, (train, _) in enumerate(fold_views):
            if fold_models[f] is None:
                fold_models[f] = fit(current.effect_names, train, _sub(seed, it, f, 0))
        passed = []
        for ci, c in enumerate(ranked):
            effs = [*current.effect_names, c.effect]
            e0s: list[np.ndarray] = []
            e1s: list[np.ndarray] = []
            fold_gains, new_fold_models = [], []
            for f, (train, held) in enumerate(fold_views):
                m0, u0 = fold_models[f]  # type: ignore[misc]
                hint = _fold_hint(m0, with_upper(train, u0), c.effect, closed, init)
                start = WithEffects(m0.base, (*m0.effects, EFFECTS[c.effect](**hint)))
                m1, u1 = fit(effs, train, _sub(seed, it, f, ci + 1), start, u0)
                r0, r1 = residuals(m0, held, u0), residuals(m1, held, u1)
                e0s += r0
                e1s += r1
                s0 = sum(float(x @ x) for x in r0)
                s1 = sum(float(x @ x) for x in r1)
                g = 1.0 - s1 / s0 if s0 > 0 and math.isfinite(s1) else -math.inf
                fold_gains.append(g)
                new_fold_models.append((m1, u1))
            sel = float(np.mean([g >= min_gain for g in fold_gains]))
            boot = block_bootstrap_gain(e0s, e1s, n_boot=n_boot, seed=_sub(seed, it, 999, ci))
            reasons = []
            if not sel > 0.5:
                reasons.append(f"lowers the held-out error by >= {min_gain:.0%} in "
                               f"{sel:.0%} of the folds (needs more than half)")
            if not boot.gain >= min_gain:
                reasons.append(f"pooled out-of-fold gain {boot.gain:.1%} < minimum "
                               f"{min_gain:.0%}")
            if not boot.p_value < cv_alpha:
                reasons.append(f"block-bootstrap p = {boot.p_value:.2g} >= {cv_alpha:g}")
            trial = Trial(it + 1, c.effect, sel, tuple(fold_gains), loss_difference_test(e0s, e1s),
                          boot, len(fold_sets), fold_kind, tuple(reasons))  # fmt: skip
            trials.append(trial)
            say(f"cv {c.effect}: folds {['%.1f%%' % (100 * g) for g in fold_gains]}, "
                f"selected in {sel:.0%}, pooled {boot.gain:.1%} (p={boot.p_value:.2g}): "
                f"{'passes' if trial.passed else 'rejected'}")  # fmt: skip
            if trial.passed:
                passed.append((len(trials) - 1, ci, c, new_fold_models))
            else:
                rejected.append(trial)
        accepted = False
        for ti, ci, c, new_fold_models in sorted(passed, key=lambda x: (-trials[x[0]].gain,
                                                                         x[1])):
            start = WithEffects(current.base, (*current.effects, EFFECTS[c.effect](**c.hint)))
            new, up1 = fit([*current.effect_names, c.effect], cal_set, _sub(seed, it, 1000, ci),
                           start, upper, show=progress)
            cal0, cal1 = mse(current, cal_set, upper), mse(new, cal_set, up1)
            if not _mean(cal1) < _mean(cal0):
                trials[ti] = replace(trials[ti], reasons=(
                    "refitted on all calibration runs it does not lower their error",))
                rejected.append(trials[ti])
                continue
            val0, val1 = mse(current, val_set, upper), mse(new, val_set, up1)
            eff = dict((e.name, e) for e in new.effects)[c.effect]
            steps.append(Step(c.effect, eff.to_dict(), new, cal0, cal1, val0, val1, trials[ti],
                              at_bound(new, up1 if upper_free else None, kind),
                              upper=up1))  # fmt: skip
            say(f"accepted {c.effect}: cal {_mean(cal0):.4g} -> {_mean(cal1):.4g}")
            current, upper = new, up1
            fold_models = list(new_fold_models)
            accepted = True
            break
        if not accepted:
            break
    # Only now: the test runs, and the flags.
    base_mse = {"cal": mse(out_base, cal_set, base_upper),
                "val": mse(out_base, val_set, base_upper),
                "test": mse(out_base, test_set, base_upper)}  # fmt: skip
    prev, prev_up = out_base, base_upper
    done: list[Step] = []
    flags: list[Flag] = []
    b_at = at_bound(out_base, base_upper if upper_free else None, kind)
    if b_at:
        flags.append(_at_bound_flag(b_at, 0, None, "baseline parameters at a bound of the "
                                    "search box: "))  # fmt: skip
    for k, s in enumerate(steps, 1):
        t0, t1 = mse(prev, test_set, prev_up), mse(s.model, test_set, s.upper)
        new_flags = []
        vg, tg, cg = _gain(s.val_before, s.val_after), _gain(t0, t1), s.cv.gain
        if s.val_before and not vg > 0:
            new_flags.append(Flag("validation_gain_not_held", k, s.effect,
                                  f"validation MSE not lower ({vg:+.1%})"))  # fmt: skip
        elif s.val_before and cg > 0 and vg < FAR_SMALLER * cg:
            new_flags.append(Flag("validation_gain_far_smaller", k, s.effect,
                                  f"validation gain {vg:.1%} is less than {FAR_SMALLER:.0%} "
                                  f"of the cross-validated gain {cg:.1%}"))  # fmt: skip
        if t0:
            ref, refname = (vg, "validation") if s.val_before else (cg, "cross-validated")
            if not tg > 0:
                new_flags.append(Flag("test_gain_not_held", k, s.effect,
                                      f"test MSE not lower ({tg:+.1%}; {refname} gain "
                                      f"{ref:+.1%})"))  # fmt: skip
            elif ref > 0 and tg < FAR_SMALLER * ref:
                new_flags.append(Flag("test_gain_far_smaller", k, s.effect,
                                      f"test gain {tg:.1%} is less than {FAR_SMALLER:.0%} of "
                                      f"the {refname} gain {ref:.1%}"))  # fmt: skip
        if s.at_bound:
            new_flags.append(_at_bound_flag(s.at_bound, k, s.effect, "at a bound of the search "
                                            "box (not an estimate): "))  # fmt: skip
        flags += new_flags
        done.append(replace(s, test_before=t0, test_after=t1,
                            flags=tuple(f.kind for f in new_flags)))  # fmt: skip
        prev, prev_up = s.model, s.upper
    # What the residual still depends on.
    try:
        unexplained = residual_structure(current, with_upper(cal_set, upper), closed_loop=closed,
                                         init=init, alpha=structure_alpha,
                                         min_share=min_structure)  # fmt: skip
    except ValueError as e:
        unexplained = {"structure_found": None, "reason": str(e)}
    if unexplained.get("structure_found"):
        kept = [s for s in unexplained["signals"] if s["keeps_structure"]]
        ev = "; ".join(f"{s['signal']} explains {s['explained']:.1%} of the residual variance "
                       f"(p = {s['p_value']:.2g})" for s in kept)  # fmt: skip
        offered = "none of the offered effects" if not done else "no further effect"
        msg = (f"{offered} explains the remaining structure: {ev}" if done else
               f"none of these: no offered effect passed the selection, yet the residual "
               f"keeps structure: {ev}")  # fmt: skip
        unexplained["message"] = msg
        flags.append(Flag("structure_unexplained", None, None, msg))
    elif unexplained.get("structure_found") is False:
        unexplained["message"] = ("no significant dependence of the residual on speed, time "
                                  "or command remains")  # fmt: skip
    splits = Splits(tuple(ids["cal_runs"]), tuple(ids["val_runs"]), tuple(ids["test_runs"]),
                    tuple(tuple(r.run_id for r in held) for _, held in fold_sets), fold_kind)
    settings = Selection(min_gain, alpha, cv_alpha, n_boot, len(fold_sets), fold_kind, tries,
                         max_effects, max_generations, starts, seed,
                         None if candidates is None else tuple(candidates), structure_alpha,
                         min_structure)  # fmt: skip
    return LoopResult(out_base, current, done, diags, rejected, upper, trials, splits, settings,
                      baseline_mse=base_mse, baseline_at_bound=b_at, baseline_upper=base_upper,
                      unexplained=unexplained, flags=flags, init=init,
                      closed_loop=closed)  # fmt: skip


def _at_bound_flag(ats: Sequence[AtBound], step: int, effect: str | None, text: str) -> Flag:
    names = tuple(a.param for a in ats)
    return Flag("at_bound", step, effect, text + ", ".join(names), names)


def _fold_hint(
    model: WithEffects, train: Sequence[Run], effect: str, closed: bool, init: str
) -> dict[str, float]:
    """The starting guess of ``effect`` from a diagnosis on the fold's training runs
    only (the effect's neutral parameters when that diagnosis cannot give one)."""
    try:
        d = diagnose(model, train, closed_loop=closed, alpha=0.999, init=init,
                     candidates=[effect])  # fmt: skip
        for c in d.candidates:
            if c.effect == effect:
                return dict(c.hint)
    except ValueError:
        pass
    cls = EFFECTS[effect]
    return dict(zip(cls.param_names(), cls.neutral, strict=True))
