"""Plain numpy reference of the base model + effects rollouts, written step by step
from the definitions in :mod:`avll.effects` (slow on purpose; the tests compare the
Rust engine against it).

Deliberately independent of the Rust engine's tricks: the braking dynamics of
``asymmetric`` are the time-scaled system ``(A/rb, B/rb, C)`` in the base
coordinates (the engine switches between two canonical forms instead); the
fractional dead time is realised by integrating the interval in two pieces with
``scipy.linalg.expm`` (the engine precombines them); the command delay keeps the
whole command history in a list; the ``sensor`` lag filters the finished true
acceleration series with ``scipy.signal.lfilter`` (the engine filters sample by
sample inside the run).

The upper-level structures (``perception``, ``speed_gains``, ``closing``,
``feedforward``, ``comfort``) are written out in :class:`Law`, one sample at a time
from their definitions in :mod:`avll.effects`: the perception delay interpolates the
signals' whole recorded history with ``numpy.interp`` (the engine keeps a ring
buffer), the feedforward's filter state follows the exact exponential step. A platoon
(:func:`platoon_effects`) is simulated car by car behind the previous car's simulated
position and speed (the engine steps it time-major), and the follower's frequency
response (:func:`frequency_response`) is evaluated from the closed-loop equations
written in the positions (the engine composes small-signal terms effect by effect).

The acceleration-level effects (saturation, power_limit, speed_drag, road_load,
grade) act on the acceleration that integrates into the actual speed: the response
itself for an acceleration command; for a speed command the derivative of the speed
response over the interval, ``abar = (y[n+1] - y[n]) / dt`` (so the actual speed
``v = y + dv`` moves by exactly ``dt (abar + e)``, ``e = actual(abar) - abar``), with
position ``p = p_lin + dp``, ``dv, dp`` integrating ``e`` held over the interval, ``K``
feeding back the actual speed, and the recorded acceleration ``C (A x + B w) + e``
(the linear right-limit derivative plus the effects' change).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from scipy.signal import lfilter

from ..effects import WithEffects
from ..models import LowerLevelModel, UpperLevel
from .lfilter import controllable_form
from .rollout import hold_map, split_delay

__all__ = ["Law", "rollout_effects", "platoon_effects", "frequency_response"]


class Law:
    """The constant-time-gap law (paper Eq. 3) with the model's upper-level
    structures, evaluated sample by sample (``dt`` the sample time)."""

    def __init__(self, model: WithEffects, upper: UpperLevel, dt: float) -> None:
        self.eff: dict[str, Any] = {e.name: e for e in model.effects}
        self.up, self.dt = upper, dt
        self.gaps: list[float] = []
        self.dvs: list[float] = []
        self.z: float | None = None
        self.prev = 0.0  # the command before the run (lower level at rest)

    def gains(self, v: float) -> tuple[float, float, float]:
        """``kg, kv, Tg`` at the own speed ``v``."""
        up, kg, kv, tg = self.up, self.up.kg, self.up.kv, self.up.Tg
        if "speed_gains" in self.eff:
            e = self.eff["speed_gains"]
            r = max(1.0 + e.cs * max(v, 0.0), 0.1)
            kg, kv, tg = up.kg / r, up.kv / r, up.Tg + e.ch * v
        return kg, kv, tg

    def gap(self, v: float) -> float:
        """The desired gap at the constant speed ``v``."""
        return self.up.Gmin + self.gains(v)[2] * v

    def __call__(self, lead_x: float, lead_v: float, x: float, v: float) -> float:
        gap, dv = lead_x - x, lead_v - v
        n = len(self.gaps)
        self.gaps.append(gap)
        self.dvs.append(dv)
        if "perception" in self.eff:
            t = np.arange(n + 1) * self.dt
            tq = n * self.dt - self.eff["perception"].tau
            gap = float(np.interp(tq, t, self.gaps))  # before the run: the first sample
            dv = float(np.interp(tq, t, self.dvs))
        kg, kv, tg = self.gains(v)
        e = gap - tg * v - self.up.Gmin
        eg, ev = kg * e, kv * dv
        if "closing" in self.eff:
            c = self.eff["closing"]
            eg = c.rg * eg if eg < 0 else eg
            ev = c.rv * ev if ev < 0 else ev
        u = eg + ev
        if "feedforward" in self.eff:
            f = self.eff["feedforward"]
            vp = v + dv
            if self.z is None:
                self.z = vp
            u += f.ka * (vp - self.z) / f.tau
            alpha = math.exp(-self.dt / f.tau)
            self.z = alpha * self.z + (1.0 - alpha) * vp
        if "comfort" in self.eff:
            c = self.eff["comfort"]
            clipped = min(max(u, -c.d_max), c.a_max)
            step = c.j_max * self.dt
            self.prev += min(max(clipped - self.prev, -step), step)
            u = self.prev
        return u


def _system(c: dict[str, float], scale: float, speed_cmd: bool) -> Any:
    """Rational part (time-scaled by ``scale``) plus integrators: (A, B, C, order)."""
    am, bm, cm = controllable_form(c)
    m = am.shape[0]
    k = 1 if speed_cmd else 2
    a = np.zeros((m + k, m + k))
    a[:m, :m] = am / scale
    a[m, :m] = cm  # v' = y (or p' = y for a speed command)
    if not speed_cmd:
        a[m + 1, m] = 1.0  # p' = v
    b = np.zeros(m + k)
    b[:m] = bm / scale
    cc = np.zeros(m + k)
    cc[:m] = cm
    return a, b, cc, m


def rollout_effects(
    model: WithEffects | LowerLevelModel,
    dt: float,
    *,
    command: Any = None,
    lead_x: Any = None,
    lead_v: Any = None,
    upper: UpperLevel | None = None,
    command_kind: str = "acceleration",
    init: str = "rest",
    v0: float = 0.0,
    x0: float = 0.0,
    exo: Mapping[str, Any] | None = None,
) -> dict[str, np.ndarray]:
    """Open loop (``command``) or closed loop (``lead_x``, ``lead_v``, ``upper``; the
    lower level starts at rest) rollout: dict of arrays a, v, x, command."""
    if isinstance(model, LowerLevelModel):
        model = WithEffects(model, ())
    eff: dict[str, Any] = {e.name: e for e in model.effects}
    c = model.base.linear()
    closed = command is None
    if closed:
        assert upper is not None, "closed loop needs upper"
        law = Law(model, upper, dt)
    speed_cmd = command_kind == "speed"
    n_samples = len(lead_x) if closed else len(command)
    rb = eff["asymmetric"].rb if "asymmetric" in eff else 1.0
    kb = eff["asymmetric"].kb if "asymmetric" in eff else 1.0
    sysa = _system(c, 1.0, speed_cmd)
    sysb = _system(c, rb, speed_cmd)
    m = sysa[3]
    i, f = split_delay(c["Td"], dt)

    def maps(sys: Any) -> Any:
        a, b, cc, _ = sys
        pa, ga = hold_map(a, b, (1.0 - f) * dt)
        pb, gb = hold_map(a, b, f * dt)
        return a, b, cc, pa, ga, pb, gb

    ma, mb = maps(sysa), maps(sysb)
    k_fb = c["K"]
    u_first = 0.0 if closed else float(command[0])
    # initial state and histories
    x = np.zeros(sysa[0].shape[0])
    w_hist = 0.0
    u_hist = 0.0
    if init == "steady" and not closed:
        w_hist = u_first / (1.0 - k_fb * c["b0"])
        x[0] = (c["a2"] if m == 2 else c["a1"]) * w_hist
        u_hist = u_first
    if speed_cmd:
        x[m] = x0
    else:
        x[m], x[m + 1] = v0, x0

    exo = exo or {}
    if "delay" in eff:
        idl, fd = split_delay(eff["delay"].tau, dt)

    def gain(w: float) -> float:
        return kb * w if w < 0 else w

    def actual(a_lin: float, v: float, n: int) -> float:
        """The acceleration that integrates into the actual speed."""
        a_act = a_lin
        if "saturation" in eff:
            a_act = min(max(a_act, -eff["saturation"].d_max), eff["saturation"].a_max)
        if "power_limit" in eff:
            e = eff["power_limit"]
            a_act = min(a_act, e.p / max(abs(v), e.v_b))
        if "speed_drag" in eff:
            e = eff["speed_drag"]
            a_act -= e.c0 * min(max(v / 0.1, -1.0), 1.0) + e.c2 * v * abs(v)
        if "road_load" in eff:
            e = eff["road_load"]
            a_act -= e.c0 * min(max(v / 0.1, -1.0), 1.0) + e.c1 * v + e.c2 * v * abs(v)
        if "grade" in eff:
            a_act -= eff["grade"].g_eff * float(exo["grade"][n])
        return a_act

    refs: list[float] = []
    cmds: list[float] = []
    prev = u_hist
    dv = dp = 0.0
    out = {k: np.full(n_samples, np.nan) for k in ("a", "v", "x", "command")}
    for n in range(n_samples):
        y = float(ma[2] @ x)
        if speed_cmd:
            v = y + dv
            p = x[m] + dp
            y_act = v
        else:
            v, p = x[m] + dv, x[m + 1] + dp
            y_act = actual(y, v, n)
        if closed:
            u = law(float(lead_x[n]), float(lead_v[n]), p, v)
        else:
            u = float(command[n])
        cmds.append(u)
        uc = u
        if "delay" in eff:
            h0 = cmds[n - idl] if n - idl >= 0 else u_hist
            h1 = cmds[n - idl - 1] if n - idl - 1 >= 0 else u_hist
            uc = (1 - fd) * h0 + fd * h1 if fd > 0 else h0
        if "rate_limit" in eff:
            step = eff["rate_limit"].j_max * dt
            prev = prev + min(max(uc - prev, -step), step)
            uc = prev
        if "deadband" in eff:
            dlt = eff["deadband"].delta
            e_ = uc - y_act if speed_cmd else uc
            dz = np.sign(e_) * max(abs(e_) - dlt, 0.0)
            uc = y_act + dz if speed_cmd else dz
        refs.append(gain(uc + k_fb * y_act))
        w0 = refs[n - i] if n - i >= 0 else gain(w_hist)
        w1 = refs[n - i - 1] if n - i - 1 >= 0 else gain(w_hist)
        demand = w0 if not speed_cmd else c["b0"] * w0 - y
        mm = mb if (rb != 1.0 and demand < 0) else ma
        a_m, b_m, c_m, pa, ga, pb, gb = mm
        wf = w1 if f > 0 else w0
        x_old = x
        if f > 0:
            x = pa @ (pb @ x + gb * w1) + ga * w0
        else:
            x = pa @ x + ga * w0
        if speed_cmd:
            # The interval's mean linear acceleration: the linear speed's increment.
            abar = (float(ma[2] @ x) - y) / dt
            e = actual(abar, v, n) - abar
            acc = float(c_m @ (a_m @ x_old) + (c_m @ b_m) * wf) + e
        else:
            acc = y_act
            e = y_act - y
        out["a"][n], out["v"][n], out["x"][n], out["command"][n] = acc, v, p, u
        if abs(y) >= 1e6 or not np.isfinite(acc):
            break
        dp += dt * dv + 0.5 * dt * dt * e
        dv += dt * e
    if "sensor" in eff:
        # The observation: a_obs = 1/(tau s + 1) a + bias, exact for a[n] held over
        # (t[n-1], t[n]]: f[n] = alpha f[n-1] + (1 - alpha) a[n], f[-1] = a[0].
        sen = eff["sensor"]
        alpha = float(np.exp(-dt / sen.tau)) if sen.tau > 0 else 0.0
        a_true = out["a"]
        f0 = np.array([alpha * a_true[0]])
        out["a"] = lfilter([1.0 - alpha], [1.0, -alpha], a_true, zi=f0)[0] + sen.bias
    return out


def platoon_effects(
    model: WithEffects | LowerLevelModel,
    lead_x: Any,
    lead_v: Any,
    dt: float,
    upper: UpperLevel,
    followers: int,
    *,
    exo: Mapping[str, Any] | None = None,
) -> dict[str, np.ndarray]:
    """``followers`` identical vehicles behind a recorded leader, car by car: follower
    ``k`` is a closed loop (:func:`rollout_effects`) behind follower ``k-1``'s simulated
    position and speed, starting at the leader's initial speed ``v0`` and ``k`` times
    the desired gap at ``v0`` behind the leader, lower level at rest. Dict of
    (follower, sample) arrays a, v, x, command; a diverged follower and every one behind
    it are NaN from its divergence on."""
    if isinstance(model, LowerLevelModel):
        model = WithEffects(model, ())
    lx, lv = np.asarray(lead_x, dtype=float), np.asarray(lead_v, dtype=float)
    gap = Law(model, upper, dt).gap(float(lv[0]))
    out = {k: np.full((followers, lx.size), np.nan) for k in ("a", "v", "x", "command")}
    px, pv = lx, lv
    for k in range(followers):
        tr = rollout_effects(model, dt, lead_x=px, lead_v=pv, upper=upper,
                             v0=float(lv[0]), x0=float(lx[0]) - (k + 1) * gap, exo=exo)
        for key in out:
            out[key][k] = tr[key]
        if not np.all(np.isfinite(tr["v"])):
            break
        px, pv = tr["x"], tr["v"]
    return out


def frequency_response(
    model: WithEffects | LowerLevelModel, upper: UpperLevel, omega: Any, *, v: float = 0.0,
    hold: float = 0.0,
) -> np.ndarray:
    """``V/V_p`` of the follower at ``s = j omega``, from the linearised closed loop
    written in the positions: the lower level ``A = G_fb U`` (``A = s² X`` the
    acceleration, ``G_fb = G e^{-tau_c s} / (1 - K G + beta/s)``, ``tau_c`` a
    ``delay`` effect's, ``beta`` the speed feedback of ``speed_drag``/``road_load``
    at ``v``), the law ``U = kg (D X_p - D X - Tg' s X) + kv D (s X_p - s X) + ka s/(tau
    s + 1) (s X + D s (X_p - X))`` with ``D = e^{-tau_p s}`` (``perception``),
    ``kg, kv`` at ``v`` (``speed_gains``) times ``(1 + r)/2`` (``closing``), ``Tg' =
    Tg + 2 ch v`` (the slope of the desired gap ``Tg v + ch v²``); solved for ``X/X_p``
    (= ``V/V_p``). A loop run at sample period ``hold`` holds the command and the inner
    feedback over each sample: ``hold / 2`` more dead time in ``G``."""
    if isinstance(model, LowerLevelModel):
        model = WithEffects(model, ())
    eff: dict[str, Any] = {e.name: e for e in model.effects}
    c = dict(model.base.linear())
    c["Td"] = c["Td"] + 0.5 * hold
    s = 1j * np.asarray(omega, dtype=float)
    beta, tau_c = 0.0, 0.0
    if "speed_drag" in eff:
        beta += 2 * eff["speed_drag"].c2 * abs(v) + (eff["speed_drag"].c0 / 0.1
                                                     if abs(v) < 0.1 else 0.0)
    if "road_load" in eff:
        e = eff["road_load"]
        beta += e.c1 + 2 * e.c2 * abs(v) + (e.c0 / 0.1 if abs(v) < 0.1 else 0.0)
    if "delay" in eff:
        tau_c = eff["delay"].tau
    kb = rb = 1.0
    if "asymmetric" in eff:  # the average of the two sides
        e = eff["asymmetric"]
        kb, rb = 0.5 * (1 + e.kb), 0.5 * (1 + e.rb)
    g = (c["b1"] * rb * kb * s + kb * c["b0"]) * np.exp(-c["Td"] * s) / (
        c["a2"] * rb**2 * s**2 + c["a1"] * rb * s + 1)
    gfb = g * np.exp(-tau_c * s) / (1 - c["K"] * g + beta / s)
    kg, kv, tg = Law(model, upper, 1.0).gains(v)
    if "speed_gains" in eff:
        tg = upper.Tg + 2 * eff["speed_gains"].ch * v
    if "closing" in eff:
        kg *= 0.5 * (1 + eff["closing"].rg)
        kv *= 0.5 * (1 + eff["closing"].rv)
    d = np.exp(-eff["perception"].tau * s) if "perception" in eff else np.ones_like(s)
    f = (eff["feedforward"].ka * s / (eff["feedforward"].tau * s + 1)
         if "feedforward" in eff else np.zeros_like(s))
    # U = cp X_p - cx X
    cp = kg * d + kv * d * s + f * d * s
    cx = kg * d + kg * tg * s + kv * d * s - f * s + f * d * s
    # s² X = gfb (cp X_p - cx X)  =>  X / X_p = gfb cp / (s² + gfb cx)
    return np.asarray(gfb * cp / (s**2 + gfb * cx))
