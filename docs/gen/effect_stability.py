"""The docs fragment docs/_generated/effect_stability.md (written by ``python -m docs.gen
--only effect-stability``): two worked examples of
:func:`avll.effect_stability.effect_stability` (the linearised thresholds side by side
and the amplification per car against the disturbance amplitude).
"""

from __future__ import annotations

from typing import Any

import avll
from avll.effect_stability import EffectStability, effect_stability
from avll.effects import Asymmetric, Saturation, WithEffects
from avll.report import num as _f


def linear_table(r: EffectStability) -> list[str]:
    """The linearised stability entries as Markdown lines."""
    out = ["| linearisation | code at the gains | \\|H(jω)\\| at ω | peak \\|H\\| (ω) | "
           "smallest stable Tg at kg, kv (s) | min stable Tg over the box (s) | "
           "kv threshold over the box |",
           "|---|---|---|---|---|---|---|"]  # fmt: skip
    for e in r.linear:
        out.append(
            f"| {e.label} | {_f(e.code, 'd')} | {_f(e.gain_at_omega, '.4g')} | "
            f"{_f(e.peak_gain, '.6g')} ({_f(e.peak_omega, '.3g')} rad/s) | "
            f"{_f(e.tg_min_at_gains, '.3f')} | {_f(e.min_stable_tg, '.3f')} | "
            f"{_f(e.kv_threshold, '.4f')} |"
        )
    return out


def amp_table(r: EffectStability) -> list[str]:
    """Amplification per car against the amplitude as Markdown lines."""
    n = r.amplification.shape[1]
    out = ["| A (m/s) | " + " | ".join(f"car {i + 1}" for i in range(n))
           + " | geometric mean | half range, last car / leader | lowest speed (m/s) |",
           "|---" * (n + 4) + "|"]  # fmt: skip
    gm = r.mean_amplification()
    for k, a in enumerate(r.amplitudes):
        cells = [_f(float(x), '.4g') if x == x else "—" for x in r.amplification[k]]
        last = r.half_range[k, -1] / r.half_range[k, 0]
        out.append(f"| {a:g} | " + " | ".join(cells) + f" | {_f(float(gm[k]), '.4g')} | "
                   f"{_f(float(last), '.4g')} | {_f(float(min(r.min_speed[k])), '.3g')} |")
    return out


def example(title: str, model: WithEffects, upper: avll.UpperLevel, **kw: Any) -> list[str]:
    """One example section."""
    r = effect_stability(model, upper, **kw)
    boxes = "kg in [0.001, 2], kv in [0, 1.2], Tg in [0, 15] s (the defaults)"
    head = [
        f"### {title}",
        "",
        f"`{r.model}` ({', '.join(f'{e.name} {e.to_dict()}' for e in model.effects)}); "
        f"upper level kg = {upper.kg:.4g}, kv = {upper.kv:.4g}, Tg = {upper.Tg:g} s; "
        f"v0 = {r.v0:g} m/s; disturbance period {r.period:.3g} s (ω = {r.omega:.4g} rad/s); "
        f"{r.amplification.shape[1]} followers, dt = {r.dt:g} s; amplitude-dependent "
        f"effects: {', '.join(r.amplitude_dependent) or 'none'}.",
        "",
        f"Linearised (codes: 0 locally unstable, 1 string unstable, 2 stable; Padé order 2; "
        f"boxes {boxes}):",
        "",
        *linear_table(r),
        "",
        f"Amplification per car (speed fundamental, car i / car i−1); a linear model gives "
        f"\\|H(jω)\\| = {_f(r.linear_gain, '.4g')} of the with-effects linearisation at every "
        "amplitude:",
        "",
        *amp_table(r),
    ]
    if r.notes:
        head += ["", "Notes: " + "; ".join(r.notes)]
    return head


def render() -> str:
    """The fragment's body (stamped and written by
    ``python -m docs.gen --only effect-stability``)."""
    second = avll.PAPER_TABLE_II["second"]
    proposed = avll.PAPER_TABLE_II["proposed"]
    lines = [
        *example("Second-order model (Table II) with an acceleration limit",
                 WithEffects(second, (Saturation(a_max=0.6, d_max=0.8),)),
                 avll.UpperLevel(kg=0.2, kv=0.3, Tg=1.5), period=20.0,
                 amplitudes=(0.1, 0.5, 1.0, 2.0, 4.0), n_cars=5),
        "",
        *example("Proposed model (Table II) with a slower, weaker brake",
                 WithEffects(proposed, (Asymmetric(kb=0.8, rb=1.5),)),
                 avll.UpperLevel(kg=0.15, kv=0.4, Tg=4.0),
                 period=20.0, amplitudes=(0.1, 1.0, 4.0), n_cars=5),
    ]  # fmt: skip
    return "\n".join(lines) + "\n"
