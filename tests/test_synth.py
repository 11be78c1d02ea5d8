"""The synthetic paper experiment: Table I, determinism, noise, physical sanity."""

from __future__ import annotations

import numpy as np
import pytest

import avll
from avll.synth import PAPER_CAL_RUNS, TABLE_I, paper_experiment


def test_table_i_and_split() -> None:
    assert len(TABLE_I) == 21
    assert TABLE_I[1] == (0.7, 2.0) and TABLE_I[19] == (0.4, 2.0)
    assert len(PAPER_CAL_RUNS) == 10


def test_runs_follow_table_i_and_are_deterministic() -> None:
    a = paper_experiment(seed=7, runs=(3, 12), duration=30.0)
    b = paper_experiment(seed=7, runs=(12,), duration=30.0)
    assert [r.run_id for r in a] == ["3", "12"]
    assert a[0].upper == avll.UpperLevel(kg=0.5, kv=0.0, Tg=1.8, Gmin=9.5)
    np.testing.assert_array_equal(a[1].a, b[0].a)  # a run does not depend on the others
    c = paper_experiment(seed=8, runs=(12,), duration=30.0)
    assert not np.array_equal(c[0].a, b[0].a)


def test_clean_run_is_the_closed_loop_of_the_true_model() -> None:
    (run,) = paper_experiment(
        seed=1, runs=(5,), duration=60.0, noise_a=0, noise_v=0, noise_x=0, quantization_a=0
    )
    m = avll.PAPER_TABLE_II["proposed"]
    # The recorded command is the upper law on the follower's states ...
    cmd = run.upper.command(run.lead_x, run.lead_v, run.x, run.v)
    np.testing.assert_allclose(run.command, cmd, atol=1e-9)
    # ... and replaying it open loop through the true model reproduces the acceleration.
    np.testing.assert_allclose(avll.simulate(m, run.command, run.dt), run.a, atol=1e-9)
    assert run.v.min() > -1e-3  # starts from standstill, no reversing
    assert np.min(run.lead_x - run.x) > 9.0


def test_noise_and_quantization() -> None:
    (clean,) = paper_experiment(
        seed=2, runs=(1,), duration=60.0, noise_a=0, noise_v=0, noise_x=0, quantization_a=0
    )
    (noisy,) = paper_experiment(seed=2, runs=(1,), duration=60.0, noise_a=0.1, quantization_a=0.05)
    resid = noisy.a - clean.a
    assert 0.08 < resid.std() < 0.12
    np.testing.assert_allclose(noisy.a / 0.05, np.round(noisy.a / 0.05), atol=1e-9)


@pytest.mark.parametrize("bad", [{"noise_a": -1.0}, {"duration": 0.1}, {"runs": (22,)}])
def test_bad_arguments(bad: dict) -> None:
    with pytest.raises(ValueError):
        paper_experiment(**bad)


def test_delay_expectation_uses_the_runs_period() -> None:
    """The delay generator's expected lag (hold - dt)/2 uses the runs' period, the one
    SYNTH_DT that paper_experiment_effects defaults to, not a second 0.05."""
    import inspect

    from avll.defaults import SYNTH_DT
    from avll.synth_effects import GENERATOR_DEFAULTS, expected_params, paper_experiment_effects

    assert inspect.signature(paper_experiment_effects).parameters["dt"].default is SYNTH_DT
    g = GENERATOR_DEFAULTS["delay"]
    assert expected_params("delay")["tau"] == g["shift"] + 0.5 * (g["hold"] - SYNTH_DT)
