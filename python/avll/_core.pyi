# Stubs of the Rust extension avll._core (checked with mypy.stubtest in the tests).
from collections.abc import Callable
from typing import Any, final

import numpy as np
import numpy.typing as npt

__version__: str
#: Digest of the Rust sources this extension was compiled from (build.rs).
SOURCE_DIGEST: str

# --- run sets (rust/bindings/runs.rs) ---
@final
class RunSet:
    def __new__(
        cls,
        offsets: list[int],
        dt: npt.NDArray[np.float64],
        a: npt.NDArray[np.float64],
        command: npt.NDArray[np.float64] | None = None,
        lead_x: npt.NDArray[np.float64] | None = None,
        lead_v: npt.NDArray[np.float64] | None = None,
        v: npt.NDArray[np.float64] | None = None,
        x: npt.NDArray[np.float64] | None = None,
        upper: npt.NDArray[np.float64] | None = None,
        exo: dict[str, npt.NDArray[np.float64]] = ...,
    ) -> RunSet: ...
    def __len__(self) -> int: ...
    @property
    def total(self) -> int: ...
    @property
    def offsets(self) -> list[int]: ...
    @property
    def index(self) -> list[int]: ...
    @property
    def exo_names(self) -> list[str]: ...
    def take(self, indices: list[int]) -> RunSet: ...
    def shares(self, other: RunSet) -> bool: ...

# --- rollouts, costs (rust/bindings/rollout.rs) ---
#: A trajectory's four arrays (a, v, x, command); a platoon's are (T, followers).
_Arrays4 = tuple[
    npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64],
    npt.NDArray[np.float64],
]

def model_names() -> list[str]: ...
def model_params(model: str) -> list[str]: ...
def simulate(
    model: str,
    params: list[float],
    command: npt.NDArray[np.float64],
    dt: float,
    init: str = "rest",
    out: npt.NDArray[np.float64] | None = None,
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
    effects: list[str] = ...,
    effect_params: list[float] = ...,
    exo: dict[str, npt.NDArray[np.float64]] = ...,
    out: Any = None,
) -> _Arrays4: ...
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
    effects: list[str] = ...,
    effect_params: list[float] = ...,
    exo: dict[str, npt.NDArray[np.float64]] = ...,
    out: Any = None,
) -> _Arrays4: ...
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
    effects: list[str] = ...,
    effect_params: list[float] = ...,
    exo: dict[str, npt.NDArray[np.float64]] = ...,
    out: Any = None,
) -> _Arrays4: ...
def synth_closed_loop(
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
    hidden: list[float],
    effects: list[str] = ...,
    effect_params: list[float] = ...,
    exo: dict[str, npt.NDArray[np.float64]] = ...,
) -> _Arrays4: ...
def batch_cost(
    model: str,
    params: npt.NDArray[np.float64],
    runs: RunSet,
    effects: list[str] = ...,
    upper_free: list[int] = ...,
    command_kind: str = "acceleration",
    weights: tuple[float, float, float] = ...,
    init: str = "rest",
    closed_loop: bool = False,
    threads: int = 0,
    out: npt.NDArray[np.float64] | None = None,
) -> npt.NDArray[np.float64]: ...
def simulate_batch(
    model: str,
    params: npt.NDArray[np.float64],
    runs: RunSet,
    effects: list[str] = ...,
    upper_free: list[int] = ...,
    command_kind: str = "acceleration",
    weights: tuple[float, float, float] = ...,
    init: str = "rest",
    closed_loop: bool = False,
    threads: int = 0,
    out: npt.NDArray[np.float64] | None = None,
) -> npt.NDArray[np.float64]: ...

# --- output arrays (rust/bindings/outbuf.rs) ---
@final
class OutputBlock: ...

def output_cache(limit: int | None = None) -> tuple[int, int]: ...

# --- calibration (rust/bindings/ga.rs) ---
def calibrate(
    model: str,
    runs: RunSet,
    lower_bounds: list[float],
    upper_bounds: list[float],
    scale: list[str],
    effects: list[str] = ...,
    upper_free: list[int] = ...,
    command_kind: str = "acceleration",
    weights: tuple[float, float, float] = ...,
    init: str = "rest",
    closed_loop: bool = False,
    problems: list[list[int]] | None = None,
    derive_seeds: bool = True,
    in_turn: bool = False,
    options: dict[str, Any] | None = None,
    initial: npt.NDArray[np.float64] | None = None,
    initial_per_problem: list[npt.NDArray[np.float64]] | None = None,
    progress: Callable[[dict[str, Any]], Any] | None = None,
    threads: int = 0,
) -> list[dict[str, Any]]: ...
def derive_seed(seed: int, k: int) -> int: ...
def ga_defaults() -> dict[str, int | float | bool]: ...
def ga_check(options: dict[str, Any] | None = None) -> dict[str, int | float | bool]: ...
def ga_auto_pop(d: int) -> int: ...

GA_AUTO_POP: tuple[int, int]
def refit_resamples(
    model: str,
    runs: RunSet,
    lower_bounds: list[float],
    upper_bounds: list[float],
    scale: list[str],
    problems: list[list[int]],
    x0: npt.NDArray[np.float64],
    atoms: list[list[int]],
    resample_weights: list[npt.NDArray[np.float64]],
    effects: list[str] = ...,
    upper_free: list[int] = ...,
    command_kind: str = "acceleration",
    weights: tuple[float, float, float] = ...,
    init: str = "rest",
    closed_loop: bool = False,
    budget: int = 0,
    step: float = 0.02,
    ftol: float = 1e-9,
    method: str = "simplex",
    progress: Callable[[dict[str, Any]], Any] | None = None,
    threads: int = 0,
) -> list[dict[str, Any]]: ...
def delay_codes_rows(
    model: str,
    params: npt.NDArray[np.float64],
    kg: list[float],
    tg: list[float],
    kv: list[float],
    budget: int = 20000,
    threads: int = 0,
) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.bool_]]: ...

# --- stability (rust/bindings/stability.rs) ---
PADE_MAX_ORDER: int
MAX_SCAN: int
MAX_GRID: int

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
def stability_boundary(
    model: str,
    params: list[float],
    axis: int,
    u: npt.NDArray[np.float64],
    w: npt.NDArray[np.float64],
    lo: float,
    hi: float,
    end: str,
    pade_order: int = 2,
    level: int = 2,
    n_scan: int = 256,
    log: bool = False,
    rtol: float = 1e-10,
    budget: int = 20000,
    threads: int = 0,
    progress: Callable[[int, int], Any] | None = None,
) -> npt.NDArray[np.float64]: ...
def stability_intervals(
    model: str,
    params: list[float],
    axis: int,
    point: list[float] | tuple[float, float, float],
    lo: float,
    hi: float,
    pade_order: int = 2,
    level: int = 2,
    n_scan: int = 256,
    log: bool = False,
    rtol: float = 1e-10,
    budget: int = 20000,
) -> list[tuple[float, float, bool, bool]]: ...
def stability_extremum(
    model: str,
    params: list[float],
    which: str,
    r1: tuple[float, float, bool],
    r2: tuple[float, float, bool],
    r3: tuple[float, float, bool],
    pade_order: int = 2,
    n_scan: int = 256,
    rtol: float = 1e-10,
    n_grid: int = 32,
    starts: int = 3,
    xtol: float = 1e-12,
    budget: int = 20000,
    threads: int = 0,
) -> tuple[float, list[float], bool, list[bool], int]: ...
def kv_threshold_grid(
    model: str,
    params: list[float],
    kg: npt.NDArray[np.float64],
    tg: npt.NDArray[np.float64],
    kv_lo: float,
    kv_hi: float,
    pade_order: int = 2,
    tol: float = 1e-5,
    budget: int = 20000,
    threads: int = 0,
) -> float: ...
def delay_points(
    model: str,
    params: list[float],
    kg: npt.NDArray[np.float64],
    tg: npt.NDArray[np.float64],
    kv: npt.NDArray[np.float64],
    budget: int = 20000,
    threads: int = 0,
) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.bool_]]: ...
def delay_string(
    model: str,
    params: list[float],
    kg: npt.NDArray[np.float64],
    tg: npt.NDArray[np.float64],
    kv: npt.NDArray[np.float64],
    budget: int = 20000,
    threads: int = 0,
) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.bool_]]: ...
def delay_margin(
    model: str,
    params: list[float],
    kg: npt.NDArray[np.float64],
    tg: npt.NDArray[np.float64],
    kv: npt.NDArray[np.float64],
    w_min: float,
    w_max: float,
    n_w: int,
    xtol: float = 1e-9,
    threads: int = 0,
) -> npt.NDArray[np.float64]: ...

# --- checks (rust/bindings/checks.rs) ---
THREADS_PER_CORE: int

def max_threads() -> int: ...
def available_cores() -> int: ...
def lower_level_stable(
    b1: float, b0: float, a2: float, a1: float, td: float, k: float, dt: float
) -> bool: ...

# --- effects (rust/bindings/effects.rs) ---
def effect_info() -> list[dict[str, object]]: ...
def linearize_effects(
    model: str,
    params: list[float],
    effects: list[str],
    effect_params: list[float],
    v: float = 0.0,
    side: int = 0,
    command_kind: str = "acceleration",
    terms: bool = False,
) -> dict[str, float]: ...
def linearize_upper(
    effects: list[str],
    effect_params: list[float],
    kg: float,
    kv: float,
    tg: float,
    gmin: float,
    v: float = 0.0,
) -> dict[str, float]: ...
def follower_response_rows(
    model: str,
    rows: npt.NDArray[np.float64],
    effects: list[str],
    omega: npt.NDArray[np.float64],
    v: float = 0.0,
    side: int = 0,
    command_kind: str = "acceleration",
    threads: int = 0,
    hold: float = 0.0,
) -> npt.NDArray[np.complex128]: ...
def follower_codes_rows(
    model: str,
    rows: npt.NDArray[np.float64],
    effects: list[str],
    v: float = 0.0,
    side: int = 0,
    command_kind: str = "acceleration",
    budget: int = 20000,
    threads: int = 0,
) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.bool_]]: ...
def follower_response(
    model: str,
    params: list[float],
    effects: list[str],
    effect_params: list[float],
    kg: float,
    kv: float,
    tg: float,
    gmin: float,
    omega: npt.NDArray[np.float64],
    v: float = 0.0,
    side: int = 0,
    hold: float = 0.0,
) -> npt.NDArray[np.complex128]: ...
