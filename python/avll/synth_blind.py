"""A blind test generator: a vehicle whose effects are realised in forms the
library does **not** use.

:mod:`avll.synth_effects` realises each effect almost as the library models it, so
recovering it is expected rather than evidence. This module simulates a
longitudinal vehicle from first principles (plain numpy/Python, not avll's effect
engine) and records what an ACC logger would: the upper-level command, the
measured acceleration, speed and position, the leader's trajectory and a grade
estimate ``exo_grade``. The lower-level library models are only approximations of
it, even for the ``clean`` scenario.

The vehicle (all parameters in :data:`DEFAULTS`, SI units)
----------------------------------------------------------
* **Command path.** The upper level (paper Eq. 3 with Table I's ``kg, Tg``,
  ``kv = 0``, evaluated on the true states at every sample) sends ``u[k]`` at
  ``t_k``; it reaches the actuator controller after ``dead_time`` plus, with
  ``jitter_max > 0``, a random extra latency uniform on ``[0, jitter_max]`` drawn
  per sample (a busy CAN bus). The actuator applies the most recent command that
  has arrived (by send time, so a packet overtaken by a newer one is never used).
* **Force demand.** ``F_d = mass u + comp``, where ``comp`` is the controller's
  feed-forward of the road load, a fraction ``road_load_comp`` of the true one
  (1 = fully compensated).
* **Separate drive and brake actuators.** The positive part of ``F_d`` is the
  engine's torque demand, tracked with a first-order lag ``drive_lag``; the
  negative part is the brake's, tracked with its own lag ``brake_lag`` (equal lags
  make the split linear; ``brake_lag > drive_lag`` is a slow brake).
* **Traction / power limit.** The delivered drive force is the smooth minimum
  ``F / (1 + (F/F_max)^6)^(1/6)`` of the engine force and
  ``F_max(v) = power / sqrt(v² + (power/f_grip)²)``: the grip limit ``f_grip`` at
  standstill, ``a <= power/(mass v)`` at speed (``power = 0``: no limit).
* **Gear-shift torque cuts.** With ``gear_up`` thresholds (m/s) the gearbox
  shifts up when the speed crosses one upwards and down ``gear_hyst`` m/s below it;
  during each shift (``shift_time`` s) the drive force is multiplied by
  ``1 - shift_depth sin²(pi t / shift_time)``. No library effect models this.
* **Driveline compliance.** The net wheel force reaches the body through a unit
  gain second-order filter (``driveline_wn``, ``driveline_zeta``).
* **Road load.** ``F_rl = c0 tanh(v / 0.3) + c1 v + c2 v²`` (rolling resistance,
  viscous losses, aerodynamic drag), in newtons.
* **Terrain.** With ``grade_rms > 0`` an elevation profile along the distance,
  the sum of four sinusoids of random wavelength (250-1500 m) and phase, scaled to
  that RMS grade; gravity ``mass g sin(atan(grade(x)))``, uncompensated. The
  logged ``exo_grade`` is an estimate: the true grade at the vehicle, low-passed
  (``grade_sensor_lag``) plus white noise ``grade_sensor_noise`` (on a flat track
  only that noise).
* **Standstill.** Brakes and resistances cannot push a stopped vehicle backwards.
* **Sensing.** The logged acceleration passes an accelerometer lag
  ``sensor_lag`` (first order), gets a bias ``sensor_bias``, white noise
  ``noise_a``, coloured AR(1) noise ``e[k] = ar1_phi e[k-1] + w[k]`` of stationary
  standard deviation ``ar1_sigma``, and quantisation ``quantization_a``. Speed and
  position get white noise ``noise_v``, ``noise_x``.

Integration: ``substeps`` (:data:`SUBSTEPS` by default) explicit steps per sample
(exact exponential updates for the first-order lags, semi-implicit Euler for the
driveline, speed and position), the command held over the sample. Randomness: one stream per
``(seed, run, purpose)`` -- leader profile, terrain, latency and noise -- so the
same seed gives the same runs, and the leader of a run is the same in every
scenario.

Scenarios (:data:`SCENARIOS`, overrides of :data:`DEFAULTS`) and what the library
may call them (:data:`ACCEPTABLE`): ``clean`` (nothing), ``noise_ar1`` (coloured
noise only: the false-positive control, nothing), ``power_limit``
(``power_limit`` or ``saturation``), ``brake_lag`` (``asymmetric``), ``gear_shift``
(no library counterpart: nothing is right), ``road_load`` (``road_load`` or
``speed_drag``), ``grade`` (``grade``), ``delay_jitter`` (``delay``), ``sensor``
(``sensor``). Every run's ``meta`` carries the scenario, the full parameter set
and how often the limits bound (``meta["truth"]``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ._limits import check_int, check_number, check_seed
from .data import Run
from .defaults import SYNTH_DT, SYNTH_NOISE
from .models import UpperLevel
from .paper import G
from .synth import GMIN, _ar1, _check_duration, _noisy, _table_i_upper, leader_profile

__all__ = [
    "DEFAULTS",
    "SCENARIOS",
    "ACCEPTABLE",
    "BLIND_RUNS",
    "SUBSTEPS",
    "blind_experiment",
    "simulate_vehicle",
    "simulate_platoon",
]

#: Explicit integration steps per sample, the default of every function here (one
#: decision): at the default 20 Hz a step of 5 ms, short against the fastest time
#: constant of :data:`DEFAULTS` (the driveline's ``1 / driveline_wn`` of 0.17 s).
SUBSTEPS: int = 10

#: The vehicle, its sensors and its network, without any effect (the ``clean``
#: scenario). Forces in N, speeds in m/s, times in s.
DEFAULTS: dict[str, Any] = {
    "mass": 1800.0,
    "dead_time": 0.25,
    "jitter_max": 0.0,
    "drive_lag": 0.35,
    "brake_lag": 0.35,
    "driveline_wn": 6.0,
    "driveline_zeta": 0.7,
    "power": 0.0,
    "f_grip": 0.8 * 1800.0 * G,
    "gear_up": (),
    "gear_hyst": 1.5,
    "shift_time": 0.5,
    "shift_depth": 0.8,
    "c0": 180.0,
    "c1": 8.0,
    "c2": 0.45,
    "road_load_comp": 1.0,
    "grade_rms": 0.0,
    "grade_sensor_lag": 0.5,
    "grade_sensor_noise": 0.002,
    "sensor_lag": 0.0,
    "sensor_bias": 0.0,
    "noise_a": SYNTH_NOISE["noise_a"],
    "ar1_sigma": 0.0,
    "ar1_phi": 0.0,
    "quantization_a": SYNTH_NOISE["quantization_a"],
    "noise_v": SYNTH_NOISE["noise_v"],
    "noise_x": SYNTH_NOISE["noise_x"],
}

#: Scenario name -> overrides of :data:`DEFAULTS` (one effect class each).
SCENARIOS: dict[str, dict[str, Any]] = {
    "clean": {},
    "noise_ar1": {"ar1_sigma": 0.08, "ar1_phi": 0.95},
    "power_limit": {"power": 14.0e3},
    "brake_lag": {"brake_lag": 0.9},
    "gear_shift": {"gear_up": (4.0, 8.0, 11.5, 15.0)},
    "road_load": {"road_load_comp": 0.0},
    "grade": {"grade_rms": 0.03},
    "delay_jitter": {"jitter_max": 0.2},
    "sensor": {"sensor_lag": 0.35, "sensor_bias": 0.10},
}

#: Scenario -> the library effects that count as finding it (empty: any accepted
#: effect is a false addition).
ACCEPTABLE: dict[str, tuple[str, ...]] = {
    "clean": (),
    "noise_ar1": (),
    "power_limit": ("power_limit", "saturation"),
    "brake_lag": ("asymmetric",),
    "gear_shift": (),
    "road_load": ("road_load", "speed_drag"),
    "grade": ("grade",),
    "delay_jitter": ("delay",),
    "sensor": ("sensor",),
}

#: Default runs (Table I numbers; each has its kg, Tg).
BLIND_RUNS: tuple[int, ...] = (1, 3, 8, 15, 12, 19, 5, 21)


def _params(scenario: str, overrides: Mapping[str, Any] | None) -> dict[str, Any]:
    if scenario not in SCENARIOS:
        raise ValueError(f"scenario: unknown {scenario!r}; known: {', '.join(SCENARIOS)}")
    p = {**DEFAULTS, **SCENARIOS[scenario]}
    for k, v in (overrides or {}).items():
        if k not in DEFAULTS:
            raise ValueError(f"overrides: unknown parameter {k!r}; known: {', '.join(DEFAULTS)}")
        p[k] = v
    for k, v in p.items():
        if k == "gear_up":
            p[k] = tuple(float(check_number(x, "gear_up", positive=True)) for x in v)
            continue
        pos = k in ("mass", "drive_lag", "brake_lag", "driveline_wn", "driveline_zeta", "f_grip",
                    "shift_time")
        p[k] = check_number(v, k, positive=pos, nonneg=not pos)
        if k == "ar1_phi" and not p[k] < 1:
            raise ValueError(f"ar1_phi: must be in [0, 1), got {v}")
    return p


def _terrain(rng: np.random.Generator, grade_rms: float) -> tuple[np.ndarray, ...]:
    """Wavenumbers, phases and amplitudes of a grade profile ``sum a_i sin(k_i x + p_i)``
    with RMS ``grade_rms`` (the derivative of an elevation profile of four sinusoids)."""
    lam = rng.uniform(250.0, 1500.0, 4)
    ph = rng.uniform(0.0, 2 * np.pi, 4)
    w = rng.uniform(0.5, 1.0, 4)
    amp = w * grade_rms / math.sqrt(0.5 * float(np.sum(w * w)))
    return 2 * np.pi / lam, ph, amp


def simulate_vehicle(
    params: Mapping[str, Any],
    lead_x: np.ndarray,
    lead_v: np.ndarray,
    dt: float,
    upper: UpperLevel,
    *,
    rng_latency: np.random.Generator,
    terrain: tuple[np.ndarray, ...] | None = None,
    substeps: int = SUBSTEPS,
    command: np.ndarray | None = None,
    v0: float = 0.0,
    x0: float | None = None,
) -> dict[str, Any]:
    """The true trajectory of the vehicle of the module doc behind a leader (closed
    loop through ``upper``) or, with ``command``, under a given command (open loop).
    ``params`` is a full parameter dict (see :data:`DEFAULTS`). Returns the true
    ``a, v, x, command, grade`` arrays, the accelerometer output before noise
    (``a_sensor``) and counters of how often the limits bound."""
    p = dict(params)
    n = lead_x.size if command is None else command.size
    m = p["mass"]
    h = dt / substeps
    e_drive = math.exp(-h / p["drive_lag"])
    e_brake = math.exp(-h / p["brake_lag"])
    e_sens = math.exp(-h / p["sensor_lag"]) if p["sensor_lag"] > 0 else 0.0
    wn, zeta = p["driveline_wn"], p["driveline_zeta"]
    power, f_grip = p["power"], p["f_grip"]
    c0, c1, c2, comp = p["c0"], p["c1"], p["c2"], p["road_load_comp"]
    ups = tuple(p["gear_up"])
    hyst, t_shift, depth = p["gear_hyst"], p["shift_time"], p["shift_depth"]
    if terrain is None or p["grade_rms"] == 0:
        kx = ph = amp = np.zeros(0)
    else:
        kx, ph, amp = terrain

    def grade_at(pos: float) -> float:
        return float(np.sum(amp * np.cos(kx * pos + ph))) if amp.size else 0.0

    # Latency of every sample: the actuator applies the newest arrived command.
    lat = p["dead_time"] + (rng_latency.uniform(0.0, p["jitter_max"], n)
                            if p["jitter_max"] > 0 else np.zeros(n))  # fmt: skip
    arrival = np.arange(n) * dt + lat
    out: dict[str, Any] = {k: np.zeros(n) for k in ("a", "v", "x", "command", "grade",
                                                    "a_sensor")}
    v = float(v0)
    pos = float(lead_x[0] - GMIN - upper.Tg * v0) if x0 is None else float(x0)
    f_drive = f_brake = 0.0  # actuator forces (N)
    fb, fb_dot = 0.0, 0.0  # body force after the driveline and its rate
    a_sens = 0.0
    gear = sum(1 for s in ups if v >= s)
    shift_left = 0.0
    applied = -1  # index of the command the actuator applies (-1: none yet, 0 command)
    cmds = out["command"]  # by send index
    limited = cut = 0

    def road_load(vv: float) -> float:
        return c0 * math.tanh(vv / 0.3) + c1 * vv + c2 * vv * vv

    def resist(vv: float, pp: float) -> float:
        return road_load(vv) + m * G * math.sin(math.atan(grade_at(pp)))

    for k in range(n):
        # Acceleration now (for the record): body force minus resistances.
        a = (fb - resist(v, pos)) / m
        if v <= 0.0 and a < 0.0:
            a = 0.0
        out["a"][k], out["v"][k], out["x"][k] = a, v, pos
        out["grade"][k] = grade_at(pos)
        out["a_sensor"][k] = a_sens
        u = float(upper.command(lead_x[k], lead_v[k], pos, v)) if command is None \
            else float(command[k])  # fmt: skip
        cmds[k] = u
        t0 = k * dt
        for j in range(substeps):
            t = t0 + j * h
            # The newest command that has arrived by t (by send index).
            hi = k
            while hi > applied and arrival[hi] > t + 1e-12:
                hi -= 1
            if hi > applied:
                applied = hi
            uc = cmds[applied] if applied >= 0 else 0.0
            f_d = m * uc + comp * road_load(v)
            d_drive = f_d if f_d > 0 else 0.0
            d_brake = -f_d if f_d < 0 else 0.0
            f_drive = d_drive + (f_drive - d_drive) * e_drive
            f_brake = d_brake + (f_brake - d_brake) * e_brake
            fw = f_drive
            if power > 0 and fw > 0:
                f_max = power / math.sqrt(v * v + (power / f_grip) ** 2)
                fw = fw / (1.0 + (fw / f_max) ** 6) ** (1.0 / 6.0)
                if fw < 0.95 * f_drive:
                    limited += 1
            if ups:
                g_new = gear
                if gear < len(ups) and v >= ups[gear]:
                    g_new = gear + 1
                elif gear > 0 and v < ups[gear - 1] - hyst:
                    g_new = gear - 1
                if g_new != gear:
                    gear, shift_left = g_new, t_shift
                if shift_left > 0:
                    fw *= 1.0 - depth * math.sin(math.pi * (t_shift - shift_left) / t_shift) ** 2
                    shift_left -= h
                    if f_drive > 0:
                        cut += 1
            f_net = fw - f_brake
            # Driveline: fb'' = wn² (f_net - fb) - 2 zeta wn fb' (semi-implicit Euler).
            fb_dot += h * (wn * wn * (f_net - fb) - 2 * zeta * wn * fb_dot)
            fb += h * fb_dot
            aa = (fb - resist(v, pos)) / m
            if v <= 0.0 and aa < 0.0:
                aa, v = 0.0, 0.0
            a_sens = aa + (a_sens - aa) * e_sens
            v_new = max(v + h * aa, 0.0)
            pos += 0.5 * h * (v + v_new)
            v = v_new
        if not (abs(v) < 1e3 and math.isfinite(v)):
            raise ValueError(f"params: the simulated vehicle diverges (sample {k})")
    total = n * substeps
    out["limited_share"] = limited / total
    out["shift_cut_share"] = cut / total
    return out


def simulate_platoon(
    params: Mapping[str, Any],
    lead_x: np.ndarray,
    lead_v: np.ndarray,
    dt: float,
    upper: UpperLevel,
    n_cars: int,
    *,
    v0: float,
    seed: int = 0,
    substeps: int = SUBSTEPS,
) -> dict[str, np.ndarray]:
    """``n_cars`` identical vehicles of the module doc (full parameter dict
    ``params``, e.g. ``{**DEFAULTS, **SCENARIOS["power_limit"]}``) behind a recorded
    leader, car by car: each follows the previous car's true position and speed
    through ``upper``, starting at ``v0`` and the equilibrium gap ``Gmin + Tg v0``
    (actuators at rest). On a flat track. Returns ``v`` and ``x`` of shape
    ``(n_cars, samples)``; a diverging car raises ``ValueError``."""
    n_cars = check_int(n_cars, "n_cars", min=1)
    seed = check_seed(seed)
    p = {**DEFAULTS, **params}
    lx, lv = np.asarray(lead_x, dtype=float), np.asarray(lead_v, dtype=float)
    vs, xs = [], []
    for i in range(n_cars):
        gap = upper.Gmin + upper.Tg * v0
        tr = simulate_vehicle(p, lx, lv, dt, upper, rng_latency=np.random.default_rng(
            [seed, i, 1321]), substeps=substeps, v0=v0, x0=float(lx[0] - gap))  # fmt: skip
        vs.append(tr["v"])
        xs.append(tr["x"])
        lx, lv = tr["x"], tr["v"]
    return {"v": np.array(vs), "x": np.array(xs)}


def blind_experiment(
    scenario: str,
    *,
    seed: int = 0,
    runs: Sequence[int] = BLIND_RUNS,
    duration: float = 120.0,
    dt: float = SYNTH_DT,
    substeps: int = SUBSTEPS,
    overrides: Mapping[str, Any] | None = None,
) -> list[Run]:
    """Runs of the blind experiment for one ``scenario`` of :data:`SCENARIOS`
    (``overrides`` change any parameter of :data:`DEFAULTS`). Each run uses Table
    I's ``kg, Tg`` for its number, starts at rest behind a leader from
    :func:`avll.synth.leader_profile`, and is an acceleration-command run with
    ``exo_grade``; ``meta["truth"]`` holds the scenario, the parameters, the
    acceptable library effects (:data:`ACCEPTABLE`) and the limits' binding
    shares. Deterministic in ``seed``."""
    seed = check_seed(seed)
    dt = check_number(dt, "dt", positive=True)
    duration = check_number(duration, "duration", positive=True)
    substeps = check_int(substeps, "substeps", min=1)
    _check_duration(duration, dt)
    p = _params(scenario, overrides)
    out = []
    for r in runs:
        r = check_int(r, "runs", min=1)
        upper = _table_i_upper(r)
        t, lx, lv = leader_profile(duration, dt, np.random.default_rng([seed, r, 1317]))
        terrain = _terrain(np.random.default_rng([seed, r, 1318]), p["grade_rms"])
        tr = simulate_vehicle(p, lx, lv, dt, upper, rng_latency=np.random.default_rng(
            [seed, r, 1319]), terrain=terrain, substeps=substeps, x0=lx[0] - GMIN)  # fmt: skip
        rng = np.random.default_rng([seed, r, 1320])
        a = tr["a_sensor"] if p["sensor_lag"] > 0 else tr["a"]
        a = _noisy(rng, a + p["sensor_bias"], p["noise_a"])
        if p["ar1_sigma"] > 0:
            a = a + _ar1(rng, t.size, p["ar1_phi"], p["ar1_sigma"])
        if p["quantization_a"] > 0:
            a = np.round(a / p["quantization_a"]) * p["quantization_a"]
        v, x = _noisy(rng, tr["v"], p["noise_v"]), _noisy(rng, tr["x"], p["noise_x"])
        # The logged grade estimate: low-passed true grade plus white noise.
        al = math.exp(-dt / p["grade_sensor_lag"]) if p["grade_sensor_lag"] > 0 else 0.0
        gs = np.empty(t.size)
        acc = float(tr["grade"][0])
        for i, gv in enumerate(tr["grade"]):
            acc = gv + (acc - gv) * al
            gs[i] = acc
        gs = gs + rng.normal(0.0, p["grade_sensor_noise"], t.size)
        truth = {
            "scenario": scenario,
            "params": {k: (list(v_) if isinstance(v_, tuple) else v_) for k, v_ in p.items()},
            "acceptable": list(ACCEPTABLE[scenario]),
            "limited_share": tr["limited_share"],
            "shift_cut_share": tr["shift_cut_share"],
        }
        out.append(
            Run(
                run_id=str(r), t=t, a=a, command_kind="acceleration", command=tr["command"],
                v=v, x=x, lead_x=lx, lead_v=lv, lead_a=np.gradient(lv, dt),
                exo={"grade": gs}, upper=upper,
                meta={"synthetic": True, "generator": "avll.synth_blind", "seed": int(seed),
                      "truth": truth},
            )
        )  # fmt: skip
    return out
