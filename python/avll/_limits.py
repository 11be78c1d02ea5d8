"""Argument guards shared by every public function: integers, the thread bound, seeds,
and the memory estimate checked before a call allocates in proportion to its inputs.

Threads: an integer (``bool`` and ``1.5`` are a ``TypeError``), ``>= 0`` (0: all cores)
and at most ``avll._core.max_threads()`` = ``THREADS_PER_CORE`` (4) x the cores available
to the process, the bound the Rust core applies too (``rust/parallel.rs``): a request
for ``10**6`` threads fails at once.

Memory: :func:`check_memory` refuses (``ValueError``: how much is needed, how to split
the work) a call whose estimated peak allocation exceeds :data:`MEMORY_FRACTION` of what
the process can still get: the smallest of ``MemAvailable`` (``/proc/meminfo``, or
``os.sysconf``), the cgroup limit and the ``RLIMIT_AS`` / ``RLIMIT_DATA`` soft limits
less what is in use; the allocation in Rust (which would abort) never happens. Calls
under :data:`SMALL` bytes are not checked (no file reads on the fast path).
"""

from __future__ import annotations

import math
import numbers
import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import _core

__all__ = [
    "SMALL", "MEMORY_FRACTION", "SEED_MAX", "check_int", "check_number", "check_threads",
    "check_seed", "check_floats", "check_range", "Range", "RANGES", "MAX_PLAUSIBLE_SPEED",
    "MAX_PLAUSIBLE_ACCEL", "MAX_POSITION_RATE", "available_memory", "check_memory", "fmt_bytes",
]

#: Allocations below this many bytes are not checked.
SMALL = 64 * 2**20
#: Share of the available memory one call may plan to use.
MEMORY_FRACTION = 0.8
#: Largest seed (the Rust core takes an unsigned 64-bit seed).
SEED_MAX = 2**64 - 1


def check_int(value: Any, name: str, *, min: int | None = None, max: int | None = None) -> int:
    """``value`` as an ``int``: a ``TypeError`` naming ``name`` unless it is an integer
    (Python or numpy; ``bool`` and ``1.5`` are refused, not truncated), a
    ``ValueError`` outside ``[min, max]``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name}: must be an integer, got {value!r}")
    v = int(value)
    if min is not None and v < min:
        raise ValueError(f"{name}: must be >= {min}, got {v}")
    if max is not None and v > max:
        raise ValueError(f"{name}: must be <= {max}, got {v}")
    return v


def check_number(value: Any, name: str, *, finite: bool = True, positive: bool = False,
                 nonneg: bool = False) -> float:
    """``value`` as a ``float``: a ``TypeError`` naming ``name`` unless it is a real
    number (``bool``, ``None`` and strings are refused), a ``ValueError`` when it is not
    finite or violates ``positive`` / ``nonneg``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name}: must be a number, got {value!r}")
    try:
        v = float(value)
    except OverflowError:
        raise ValueError(f"{name}: {value!r:.40}... is too large for a float") from None
    if finite and not math.isfinite(v):
        raise ValueError(f"{name}: must be finite, got {v}")
    if positive and not v > 0:
        raise ValueError(f"{name}: must be > 0, got {v}")
    if nonneg and not v >= 0:
        raise ValueError(f"{name}: must be >= 0, got {v}")
    return v


def check_floats(value: Any, name: str) -> np.ndarray:
    """``value`` as a float64 array (any shape), or a ``ValueError`` naming ``name``."""
    if isinstance(value, (str, bytes)) or value is None:
        raise ValueError(f"{name}: expected an array of numbers, got {value!r:.40}")
    try:
        a = np.asarray(value)
        if a.dtype.kind == "c":  # a cast would drop the imaginary part with a mere warning
            raise ValueError(f"complex values are not accepted (dtype {a.dtype})")
        return a.astype(np.float64, copy=False)
    except (TypeError, ValueError, OverflowError) as e:
        raise ValueError(f"{name}: expected an array of numbers ({e})") from None


#: Speeds above this (m/s, 252 km/h) are not plausible for road vehicles.
MAX_PLAUSIBLE_SPEED = 70.0
#: Accelerations beyond this (m/s²) are not plausible for road vehicles.
MAX_PLAUSIBLE_ACCEL = 15.0


@dataclass(frozen=True)
class Range:
    """Plausible range ``[lo, hi]`` (outside: a warning) and the hard limit ``hard``
    on the magnitude (beyond: an error) of one kind of signal, in SI ``unit``."""

    lo: float
    hi: float
    hard: float
    unit: str


#: Physical ranges by kind of signal (see the module doc).
RANGES: dict[str, Range] = {
    "speed": Range(-1.0, 50.0, MAX_PLAUSIBLE_SPEED, "m/s"),
    "acceleration": Range(-10.0, 10.0, MAX_PLAUSIBLE_ACCEL, "m/s²"),
    "time_step": Range(1e-3, 1.0, 2.0, "s"),
    "grade": Range(-0.2, 0.2, 1.0, ""),
    "position": Range(-1e8, 1e8, 1e8, "m"),
    "other": Range(-1e12, 1e12, 1e12, ""),
}
#: Largest plausible speed implied by two consecutive positions (m/s).
MAX_POSITION_RATE = 70.0


def check_range(arr: np.ndarray, kind: str, name: str,
                error: type[ValueError] = ValueError) -> None:
    """Refuses (``error`` naming ``name`` and the sample) a value of the signal ``arr``
    beyond the hard limit of its ``kind`` in :data:`RANGES` (``"other"`` for a kind it
    does not list). The API checks exogenous signals as ``"other"``: a synthetic one
    may carry any disturbance (:mod:`avll.synth_platoon` drives a follower through the
    grade channel in m/s²), so only a magnitude no signal can have is refused there."""
    rg = RANGES.get(kind, RANGES["other"])
    bad = np.flatnonzero(np.abs(arr) > rg.hard)
    if bad.size:
        i = int(bad[0])
        raise error(f"{name}: sample {i} is {arr[i]:g}, beyond the hard limit "
                    f"+-{rg.hard:g}{(' ' + rg.unit) if rg.unit else ''}")


def check_choice(value: Any, name: str, choices: tuple[str, ...]) -> str:
    """``value`` if it is one of the strings ``choices``, else a ``ValueError`` naming
    ``name`` (``None`` and other types included)."""
    if not isinstance(value, str) or value not in choices:
        raise ValueError(f"{name}: must be {' or '.join(map(repr, choices))}, got {value!r:.40}")
    return value


def max_threads() -> int:
    """The largest accepted ``threads`` (from the Rust core: 4 x the available cores)."""
    return int(_core.max_threads())


def check_threads(threads: Any, name: str = "threads") -> int:
    """``threads`` checked against the machine (see the module doc); returns the int."""
    n = check_int(threads, name, min=0)
    top = max_threads()
    if n > top:
        raise ValueError(
            f"{name}: {n} is more than {_core.THREADS_PER_CORE} x the "
            f"{_core.available_cores()} available cores (at most {top}); use 0 for all cores"
        )
    return n


def check_seed(seed: Any, name: str = "seed") -> int:
    """A seed: an integer in ``0 .. 2**64 - 1``."""
    return check_int(seed, name, min=0, max=SEED_MAX)


def _status_kb(key: str, path: str = "/proc/self/status") -> int | None:
    """The ``key:`` line (a size in kB) of a ``/proc`` file, in bytes (None: not there)."""
    try:
        with open(path, encoding="ascii") as f:
            for line in f:
                if line.startswith(key + ":"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _meminfo_available() -> int | None:
    m = _status_kb("MemAvailable", "/proc/meminfo")
    if m is not None:
        return m
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


def _cgroup_available() -> int | None:
    try:
        with open("/proc/self/cgroup", encoding="ascii") as f:
            rel = next((ln.split(":", 2)[2].strip() for ln in f if ln.startswith("0::")), None)
        if rel is None:
            return None
        base = os.path.join("/sys/fs/cgroup", rel.lstrip("/"))
        with open(os.path.join(base, "memory.max"), encoding="ascii") as f:
            lim = f.read().strip()
        if lim == "max":
            return None
        with open(os.path.join(base, "memory.current"), encoding="ascii") as f:
            cur = int(f.read().strip())
        return max(0, int(lim) - cur)
    except (OSError, ValueError, StopIteration, IndexError):
        return None


def _rlimit_available() -> list[tuple[int, str]]:
    out: list[tuple[int, str]] = []
    try:
        import resource
    except ImportError:  # pragma: no cover - not POSIX
        return out
    for lim, key, label in ((resource.RLIMIT_AS, "VmSize", "RLIMIT_AS"),
                            (getattr(resource, "RLIMIT_DATA", None), "VmData", "RLIMIT_DATA")):
        if lim is None:
            continue
        soft, _ = resource.getrlimit(lim)
        if soft == resource.RLIM_INFINITY or soft < 0:
            continue
        used = _status_kb(key) or 0
        out.append((max(0, soft - used), f"the {label} limit of {fmt_bytes(soft)}"))
    return out


def available_memory() -> tuple[int | None, str]:
    """Bytes this process can still allocate (``None`` if unknown) and what limits it."""
    cands = [(n, what) for n, what in ((_meminfo_available(), "available memory"),
                                       (_cgroup_available(), "the cgroup memory limit"))
             if n is not None]
    cands += _rlimit_available()
    return min(cands) if cands else (None, "unknown")


def fmt_bytes(n: float) -> str:
    """``1.5 GB`` style (powers of 1000)."""
    for unit in ("B", "kB", "MB", "GB", "TB"):
        if abs(n) < 1000:
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000.0
    return f"{n:.1f} PB"


def check_memory(nbytes: float, what: str, hint: str, *, per: float | None = None,
                 unit: str = "") -> None:
    """Refuses (``ValueError``) a call whose estimated peak allocation ``nbytes`` does
    not fit in :data:`MEMORY_FRACTION` of :func:`available_memory`. ``what`` names the
    call and the arguments that decide its size, ``hint`` says how to chunk; with
    ``per`` (bytes per ``unit``, e.g. per follower) the message says how many fit."""
    if not math.isfinite(nbytes) or nbytes >= 2**62:
        raise ValueError(f"{what}: needs about {fmt_bytes(nbytes)}, more than any machine "
                         f"has; {hint}")
    if nbytes < SMALL:
        return
    avail, source = available_memory()
    if avail is None:
        return
    if nbytes > MEMORY_FRACTION * avail:
        fit = ""
        if per is not None and per > 0:
            fit = f" (at most {int(MEMORY_FRACTION * avail // per)} {unit} per call fit)"
        raise ValueError(
            f"{what}: needs about {fmt_bytes(nbytes)} but only {fmt_bytes(avail)} can be "
            f"allocated ({source}); {hint}{fit}"
        )


def check_weights(weights: Any, name: str = "weights") -> tuple[float, float, float]:
    """The objective's weights ``(wa, wv, wx)`` as three finite floats ``>= 0``, not all
    zero, or a ``ValueError``/``TypeError`` naming ``name``."""
    try:
        if len(weights) != 3:
            raise ValueError(f"{name}: expected 3 values (a, v, x), got {len(weights)}")
        wa, wv, wx = (check_number(w, name, nonneg=True) for w in weights)
    except TypeError:
        raise TypeError(f"{name}: expected 3 numbers (a, v, x), got {weights!r}") from None
    if wa + wv + wx <= 0:
        raise ValueError(f"{name}: at least one weight must be > 0, got {tuple(weights)!r}")
    return wa, wv, wx
