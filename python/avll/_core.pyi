# Stubs of the Rust extension avll._core (checked with mypy.stubtest in the tests).
from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

__version__: str

def model_params(model: str) -> list[str]: ...
def simulate(
    model: str,
    params: list[float],
    command: npt.NDArray[np.float64],
    dt: float,
    init: str = "rest",
) -> npt.NDArray[np.float64]: ...
def simulate_full(
    model: str,
    params: list[float],
    command: npt.NDArray[np.float64],
    dt: float,
    command_kind: str = "acceleration",
    init: str = "rest",
    v0: float = 0.0,
    x0: float = 0.0,
) -> dict[str, npt.NDArray[np.float64]]: ...
def closed_loop(
    model: str,
    params: list[float],
    lead_x: npt.NDArray[np.float64],
    lead_v: npt.NDArray[np.float64],
    dt: float,
    kg: float,
    kv: float,
    tg: float,
    gmin: float,
    v0: float,
    x0: float,
) -> dict[str, npt.NDArray[np.float64]]: ...
def platoon(
    model: str,
    params: list[float],
    lead_x: npt.NDArray[np.float64],
    lead_v: npt.NDArray[np.float64],
    dt: float,
    kg: float,
    kv: float,
    tg: float,
    gmin: float,
    followers: int,
) -> dict[str, npt.NDArray[np.float64]]: ...
def batch_cost(
    model: str,
    params: npt.NDArray[np.float64],
    offsets: list[int],
    dt: npt.NDArray[np.float64],
    a: npt.NDArray[np.float64],
    command: npt.NDArray[np.float64] | None = None,
    lead_x: npt.NDArray[np.float64] | None = None,
    lead_v: npt.NDArray[np.float64] | None = None,
    v: npt.NDArray[np.float64] | None = None,
    x: npt.NDArray[np.float64] | None = None,
    upper: npt.NDArray[np.float64] | None = None,
    upper_free: list[int] = ...,
    command_kind: str = "acceleration",
    weights: tuple[float, float, float] = ...,
    init: str = "rest",
    closed_loop: bool = False,
    threads: int = 0,
) -> npt.NDArray[np.float64]: ...
def calibrate(
    model: str,
    offsets: list[int],
    dt: npt.NDArray[np.float64],
    a: npt.NDArray[np.float64],
    lower_bounds: list[float],
    upper_bounds: list[float],
    scale: list[str],
    command: npt.NDArray[np.float64] | None = None,
    lead_x: npt.NDArray[np.float64] | None = None,
    lead_v: npt.NDArray[np.float64] | None = None,
    v: npt.NDArray[np.float64] | None = None,
    x: npt.NDArray[np.float64] | None = None,
    upper: npt.NDArray[np.float64] | None = None,
    upper_free: list[int] = ...,
    command_kind: str = "acceleration",
    weights: tuple[float, float, float] = ...,
    init: str = "rest",
    closed_loop: bool = False,
    problems: list[list[int]] | None = None,
    derive_seeds: bool = True,
    stop_all_at_target: bool = False,
    seed: int = 0,
    pop_size: int = 0,
    max_generations: int = 300,
    stall_generations: int = 20,
    ftol: float = 0.0001,
    xtol: float = 1e-08,
    target: float = ...,
    tournament: int = 2,
    crossover_prob: float = 0.9,
    eta_c: float = 10.0,
    mutation_prob: float = 0.0,
    eta_m: float = 20.0,
    plus: bool = True,
    elite: int = 0,
    polish: bool = True,
    polish_max_evals: int = 0,
    local_every: int = 3,
    local_evals: int = 0,
    initial: npt.NDArray[np.float64] | None = None,
    progress: Callable[[dict[str, Any]], Any] | None = None,
    threads: int = 0,
) -> list[dict[str, Any]]: ...
def derive_seed(seed: int, k: int) -> int: ...

# --- stability (rust/bindings/stability.rs) ---
PADE_MAX_ORDER: int

def stability_map(
    model: str,
    params: list[float],
    kg: npt.NDArray[np.float64],
    tg: npt.NDArray[np.float64],
    kv: npt.NDArray[np.float64],
    pade_order: int = 2,
    threads: int = 0,
    progress: Callable[[int, int], object] | None = None,
) -> npt.NDArray[np.uint8]: ...
def stability_points(
    model: str,
    params: list[float],
    kg: npt.NDArray[np.float64],
    tg: npt.NDArray[np.float64],
    kv: npt.NDArray[np.float64],
    pade_order: int = 2,
    threads: int = 0,
) -> npt.NDArray[np.uint8]: ...
def stability_polys(
    model: str,
    params: list[float],
    kg: float,
    tg: float,
    kv: float,
    pade_order: int = 2,
) -> tuple[list[float], list[float], list[float]]: ...
def pade_den(order: int, td: float) -> list[float]: ...

# --- checks (rust/bindings/checks.rs) ---
THREADS_PER_CORE: int

def max_threads() -> int: ...
def available_cores() -> int: ...
def lower_level_stable(
    b1: float, b0: float, a2: float, a1: float, td: float, k: float, dt: float
) -> bool: ...

# --- effects (rust/bindings/effects.rs) ---
def effect_info() -> list[dict[str, object]]: ...
def simulate_effects(
    model: str,
    params: list[float],
    effects: list[str],
    effect_params: list[float],
    command: npt.NDArray[np.float64],
    dt: float,
    command_kind: str = "acceleration",
    init: str = "rest",
    v0: float = 0.0,
    x0: float = 0.0,
    exo: dict[str, npt.NDArray[np.float64]] = ...,
) -> dict[str, npt.NDArray[np.float64]]: ...
def closed_loop_effects(
    model: str,
    params: list[float],
    effects: list[str],
    effect_params: list[float],
    lead_x: npt.NDArray[np.float64],
    lead_v: npt.NDArray[np.float64],
    dt: float,
    kg: float,
    kv: float,
    tg: float,
    gmin: float,
    v0: float,
    x0: float,
    exo: dict[str, npt.NDArray[np.float64]] = ...,
) -> dict[str, npt.NDArray[np.float64]]: ...
def linearize_effects(
    model: str,
    params: list[float],
    effects: list[str],
    effect_params: list[float],
    v: float = 0.0,
    side: int = 0,
    command_kind: str = "acceleration",
) -> dict[str, float]: ...
def batch_cost_effects(
    model: str,
    effects: list[str],
    params: npt.NDArray[np.float64],
    offsets: list[int],
    dt: npt.NDArray[np.float64],
    a: npt.NDArray[np.float64],
    command: npt.NDArray[np.float64] | None = None,
    lead_x: npt.NDArray[np.float64] | None = None,
    lead_v: npt.NDArray[np.float64] | None = None,
    v: npt.NDArray[np.float64] | None = None,
    x: npt.NDArray[np.float64] | None = None,
    upper: npt.NDArray[np.float64] | None = None,
    upper_free: list[int] = ...,
    command_kind: str = "acceleration",
    weights: tuple[float, float, float] = ...,
    init: str = "rest",
    closed_loop: bool = False,
    exo: dict[str, npt.NDArray[np.float64]] = ...,
    threads: int = 0,
) -> npt.NDArray[np.float64]: ...
def calibrate_effects(
    model: str,
    effects: list[str],
    offsets: list[int],
    dt: npt.NDArray[np.float64],
    a: npt.NDArray[np.float64],
    lower_bounds: list[float],
    upper_bounds: list[float],
    scale: list[str],
    command: npt.NDArray[np.float64] | None = None,
    lead_x: npt.NDArray[np.float64] | None = None,
    lead_v: npt.NDArray[np.float64] | None = None,
    v: npt.NDArray[np.float64] | None = None,
    x: npt.NDArray[np.float64] | None = None,
    upper: npt.NDArray[np.float64] | None = None,
    upper_free: list[int] = ...,
    command_kind: str = "acceleration",
    weights: tuple[float, float, float] = ...,
    init: str = "rest",
    closed_loop: bool = False,
    exo: dict[str, npt.NDArray[np.float64]] = ...,
    seed: int = 0,
    pop_size: int = 0,
    max_generations: int = 300,
    stall_generations: int = 20,
    ftol: float = 1e-4,
    polish: bool = True,
    local_every: int = 3,
    initial: npt.NDArray[np.float64] | None = None,
    progress: Callable[[dict[str, object]], object] | None = None,
    threads: int = 0,
) -> dict[str, object]: ...
