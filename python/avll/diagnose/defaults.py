"""Defaults of the residual loop's rule (light: no heavy imports, so that the CLI's
help can state them without loading the loop)."""

from __future__ import annotations

__all__ = ["MIN_GAIN", "DEFAULT_FOLDS", "DEFAULT_BLOCKS", "FAR_SMALLER", "MIN_BLOCK", "ALPHA",
           "MIN_SHARE", "MAX_EFFECTS", "N_BOOT"]

#: Default minimum effect size: the relative reduction of the out-of-fold MSE an
#: effect must bring (in most folds and pooled) to be accepted.
MIN_GAIN: float = 0.05
#: Default number of folds (capped at the number of calibration runs).
DEFAULT_FOLDS: int = 5
#: Default number of contiguous blocks when there is a single calibration run.
DEFAULT_BLOCKS: int = 3
#: A test gain below this share of the validation (or cross-validated) gain, or a
#: validation gain below this share of the cross-validated gain, is flagged as "far
#: smaller".
FAR_SMALLER: float = 0.5
#: A block fold needs at least this many samples.
MIN_BLOCK: int = 50
#: Significance level of the residual's signature tests (each effect's, and whether the
#: final residual keeps structure).
ALPHA: float = 1e-3
#: Smallest share of the residual's variance a structure must explain to count.
MIN_SHARE: float = 0.02
#: Effects accepted at most by one loop.
MAX_EFFECTS: int = 3
#: Replicates of the moving-block bootstrap of a gain.
N_BOOT: int = 2000
