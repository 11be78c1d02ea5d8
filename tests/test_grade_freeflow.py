"""Road grade in the AstaZero free-flow stretches: the generated page
(``avll.studies.grade_freeflow`` -> ``docs/_generated/grade_freeflow.*``) is recomputed and
compared, and what it reports is pinned: the residual of the calibrated base model
depends on the grade, but the fitted grade gain is a small fraction of an uncompensated
grade (the ACC compensates it) and the cross-validated loop does not accept ``grade``."""

from __future__ import annotations

import json
from pathlib import Path
from types import ModuleType

import pytest

pytestmark = pytest.mark.data

ROOT = Path(__file__).resolve().parents[1]
STALE = "stale: rerun python -m docs.gen --only grade-freeflow (then commit docs/_generated)"


def _script() -> ModuleType:
    from avll.studies import grade_freeflow

    return grade_freeflow


def test_free_flow_grade_numbers_reproduce(shared_data: Path) -> None:
    mod = _script()
    committed = json.loads((ROOT / "docs" / "_generated" / "grade_freeflow.json").read_text())
    cal, val, test = mod.split(shared_data)
    assert [r.run_id for r in cal] == committed["cal"]
    assert [r.run_id for r in test] == committed["test"]
    fit = mod.grade_fit(cal, committed["max_generations"])
    for k in ("corr_residual_grade", "n_eff", "grade_std", "g_eff"):
        assert fit[k] == pytest.approx(committed["fit"][k], rel=1e-6, abs=1e-9), (k, STALE)
    # What the page concludes from these numbers:
    assert abs(fit["corr_residual_grade"]) > 2 * fit["corr_se"]  # the residual sees the grade
    assert abs(fit["g_eff"]) < 0.1 * mod.G  # ... but the ACC compensates most of it
    from avll.diagnose import effect_loop

    loop = effect_loop(mod.BASE, cal, val, test_runs=test, seed=0,
                       max_generations=committed["max_generations"], max_effects=2).to_dict()
    assert loop["effects"] == committed["loop"]["effects"], STALE
    assert "grade" not in loop["effects"]
    text = (ROOT / "docs" / "_generated" / "grade_freeflow.md").read_text()
    assert mod.conclusion(committed) in text, STALE
