"""Labelled, chunked and distributed stability maps.

* :func:`map_dataset`: a map as an ``xarray.DataArray`` of codes with dims
  ``("kg", "Tg", "kv")`` and the model, Padé order and code meanings as attributes.
  With ``chunks`` it is Dask-backed: every chunk is computed by the Rust kernel
  (``dask.array.map_blocks``) on the current Dask scheduler or
  ``distributed.Client`` when it is needed, so :func:`write_map` streams a map
  larger than memory to Zarr with memory bounded by a few chunks (and marks the store
  complete when the last chunk is written; a plain ``.to_zarr`` does not).
* :func:`map_thresholds`: the thresholds of a map (eager or Dask-backed) by
  reductions over the chunks, without materialising the map.
* :func:`write_map` / :func:`open_map`: Zarr or netCDF files (written to a temporary
  name, then renamed; a Zarr store carries a completeness marker written last, and
  :func:`open_map` refuses a store without it).
* :func:`sweep`, :func:`calibrate_many_distributed`, :func:`min_stable_tg_samples`:
  many maps (models × Padé orders × parameter samples), many calibrations and many
  infima on a ``dask.distributed`` client (a local cluster by default), with the same
  results as in one process.
* :func:`stability_probability`: the probability of stability over parameter
  samples (e.g. bootstrap samples of a calibration, :func:`models_from_bootstrap`).

xarray is a dependency of avll; Dask, distributed, Zarr and h5netcdf come with the
``dask`` extra (``pip install avll[dask]``). All are imported inside the functions.
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from typing import Any

import numpy as np

from . import _core
from . import stability as S
from ._limits import check_int, check_memory, check_threads
from .defaults import LEVEL
from .models import LowerLevelModel
from .paper import PADE_ORDER

__all__ = [
    "DIMS",
    "map_dataset",
    "map_thresholds",
    "write_map",
    "open_map",
    "COMPLETE_MARKER",
    "sweep",
    "stability_probability",
    "min_stable_tg_samples",
    "models_from_bootstrap",
    "calibrate_many_distributed",
    "bootstrap_distributed",
    "local_client",
]

#: Dimension names of a map.
DIMS = ("kg", "Tg", "kv")
_DIM_ALIASES = {"kg": "kg", "Tg": "Tg", "tg": "Tg", "kv": "kv"}


def _chunk_sizes(chunks: Mapping[str, int], shape: tuple[int, int, int]) -> tuple[int, ...]:
    if not isinstance(chunks, Mapping):
        raise ValueError(f"chunks: expected a dict of dim -> chunk length, got {chunks!r}")
    sizes = dict(zip(DIMS, shape, strict=True))
    out = dict(sizes)
    for k, v in chunks.items():
        if k not in _DIM_ALIASES:
            raise ValueError(f"chunks: unknown dimension {k!r}; dims are {', '.join(DIMS)}")
        if isinstance(v, bool) or int(v) != v or int(v) < 1:
            raise ValueError(f"chunks: chunk length of {k!r} must be an integer >= 1, got {v!r}")
        d = _DIM_ALIASES[k]
        out[d] = min(int(v), sizes[d])
    return tuple(out[d] for d in DIMS)


def _block_memory(what: str, points: float, order: int, hint: str) -> None:
    """The memory check of one map computation; peak bytes per grid point: the uint8 code
    for a Padé map, the three float64 meshgrid axes, the code and the settled flag for
    the exact delay (``order == 0``)."""
    S._grid_memory(what, points, 1.0 if order else S._POINT_BYTES, hint)


_CHUNK_HINT = "use smaller chunks (e.g. chunks={'kg': 200, 'Tg': 200})"


def _map_block(
    model_name: str,
    params: list[float],
    kg: np.ndarray,
    tg: np.ndarray,
    kv: np.ndarray,
    order: int,
    threads: int,
    budget: int,
    block_info: Any = None,
) -> np.ndarray:
    """One chunk of a map, by the Rust kernel (a Dask block function)."""
    loc = block_info[None]["array-location"]
    # copies: arrays that travelled through a distributed scheduler may be unaligned
    k, t, v = (np.array(a[lo:hi], dtype=np.float64)
               for a, (lo, hi) in zip((kg, tg, kv), loc, strict=True))
    # checked where the chunk is computed (a worker may have less memory than the client)
    _block_memory(f"map_dataset: a chunk of {k.size} kg x {t.size} Tg x {v.size} kv",
                  float(k.size) * t.size * v.size, order, _CHUNK_HINT)
    if order == 0:
        g = [np.ascontiguousarray(a.ravel()) for a in np.meshgrid(k, t, v, indexing="ij")]
        codes, _ = _core.delay_points(model_name, params, g[0], g[1], g[2], budget, threads)
        return codes.reshape(k.size, t.size, v.size)
    return _core.stability_map(model_name, params, k, t, v, order, threads)


def map_dataset(
    model: LowerLevelModel,
    kg: Any,
    tg: Any,
    kv: Any,
    pade_order: int | None = PADE_ORDER,
    chunks: Mapping[str, int] | None = None,
    *,
    threads: int | None = None,
    progress: bool = False,
    budget: int = S.EXACT_BUDGET,
) -> Any:
    """A stability map as an ``xarray.DataArray`` of uint8 codes, dims
    ``("kg", "Tg", "kv")``, with the model, its parameters, the Padé order
    (``"exact"`` for ``pade_order=None``, the exact-delay test) and the code meanings
    as attributes.

    Without ``chunks`` the map is computed now (as :func:`avll.stability_map`, which
    keeps returning the plain array). With ``chunks`` (a dict of dim -> chunk length,
    e.g. ``{"kg": 500, "Tg": 500}``; missing dims are not split) the array is
    Dask-backed and nothing is computed until it is needed: every chunk is computed
    by the Rust kernel with ``threads`` threads (default 1 per chunk, so the
    scheduler's workers give the parallelism) on the current Dask scheduler or
    client; :func:`write_map` streams it to a Zarr store chunk by chunk (not
    ``.to_zarr``: see there). The codes are the same as the eager map's, bit for bit.
    """
    import xarray as xr

    kg_a, tg_a, kv_a = S._axis("kg", kg), S._axis("tg", tg), S._axis("kv", kv)
    order = S._pade_arg(pade_order)
    name, p = S._model(model)
    coords = {"kg": kg_a, "Tg": tg_a, "kv": kv_a}
    attrs = {**S._attrs(model, pade_order), "codes": S.CODE_MEANINGS,
             "code_local_unstable": S.LOCAL_UNSTABLE,
             "code_string_unstable": S.STRING_UNSTABLE, "code_stable": S.STABLE}
    budget = check_int(budget, "budget", min=1)
    if chunks is None:
        th = check_threads(0 if threads is None else threads)
        if order == 0:
            _block_memory(f"map_dataset: {kg_a.size} kg x {tg_a.size} Tg x {kv_a.size} kv",
                          float(kg_a.size) * tg_a.size * kv_a.size, order,
                          "pass chunks= to compute it chunk by chunk, or split the grid")
            data, _ = S._exact_grid(model, kg_a, tg_a, kv_a, threads=th, budget=budget)
        else:
            data = S.stability_map(model, kg_a, tg_a, kv_a, order, threads=th, progress=progress)
        return xr.DataArray(data, dims=DIMS, coords=coords, name="codes", attrs=attrs)
    import dask.array as da
    from dask.base import tokenize

    th = check_threads(1 if threads is None else threads)
    shape = (kg_a.size, tg_a.size, kv_a.size)
    cs = _chunk_sizes(chunks, shape)
    # one chunk must fit here too (a local scheduler computes it in this process)
    _block_memory(f"map_dataset: a chunk of {cs[0]} kg x {cs[1]} Tg x {cs[2]} kv",
                  float(cs[0]) * cs[1] * cs[2], order, _CHUNK_HINT)
    tok = tokenize(name, p, kg_a, tg_a, kv_a, order, budget)
    arr = da.map_blocks(
        _map_block, name, p, kg_a, tg_a, kv_a, order, th, int(budget), dtype=np.uint8,
        chunks=da.core.normalize_chunks(cs, shape), meta=np.empty((0, 0, 0), dtype=np.uint8),
        name=f"avll-stability-map-{tok}",
    )
    return xr.DataArray(arr, dims=DIMS, coords=coords, name="codes", attrs=attrs)


def map_thresholds(codes: Any) -> S.Thresholds:
    """The :class:`avll.stability.Thresholds` of a labelled map (from
    :func:`map_dataset`, eager or Dask-backed). For a Dask-backed map only the
    reductions ``any over Tg`` ((kg, kv)) and ``any over kg`` ((Tg, kv)) are computed,
    chunk by chunk: the map itself is never held in memory."""
    import xarray as xr

    if not isinstance(codes, xr.DataArray) or tuple(codes.dims) != DIMS:
        raise ValueError(f"codes: expected a DataArray with dims {DIMS} (from map_dataset)")
    return S.thresholds(codes)


def _format(path: str, fmt: str | None) -> str:
    if fmt is None:
        low = path.rstrip("/").lower()
        if low.endswith(".zarr"):
            return "zarr"
        if low.endswith((".nc", ".nc4", ".netcdf")):
            return "netcdf"
        raise ValueError(f"path: cannot tell the format of {path!r}; use .zarr or .nc, "
                         "or pass format='zarr' / 'netcdf'")
    if fmt not in ("zarr", "netcdf"):
        raise ValueError(f"format: must be 'zarr' or 'netcdf', got {fmt!r}")
    return fmt


#: The completeness marker of a Zarr store written by :func:`write_map`: an empty Zarr
#: group of this name in the store's root (its attributes say who wrote it and the
#: variables' shapes), created after every chunk and the metadata are on disk. xarray
#: does not read groups, so copying the map with ``.to_zarr`` does not copy the mark.
#: :func:`open_map` refuses a Zarr store without it.
COMPLETE_MARKER = "avll_complete"


def _remove_tree(path: str) -> None:
    """Removes a folder, also when a straggling writer recreates it meanwhile."""
    import time

    for _ in range(20):
        shutil.rmtree(path, ignore_errors=True)
        if not os.path.exists(path):
            time.sleep(0.05)
            if not os.path.exists(path):
                return
    shutil.rmtree(path, ignore_errors=True)  # pragma: no cover - a writer that never stops


def _to_zarr(ds: Any, path: str) -> None:
    """``ds.to_zarr(path)``; a Dask-backed dataset on the default threaded scheduler
    runs on a thread pool that is drained (the chunks in flight finished) before this
    returns or raises, so no chunk is written into ``path`` after a Ctrl-C."""
    lazy = any(hasattr(v.data, "dask") for v in ds.variables.values())
    if lazy:
        import dask
        import dask.threaded
        from dask.base import get_scheduler

        sched = get_scheduler()
        if sched is None or sched is dask.threaded.get:
            from concurrent.futures import ThreadPoolExecutor

            from . import _atomic

            pool = ThreadPoolExecutor(max_workers=os.cpu_count() or 1)
            try:
                with dask.config.set(scheduler="threads", pool=pool):
                    ds.to_zarr(path, mode="w", consolidated=False)
            finally:
                with _atomic.deferred_sigint():
                    pool.shutdown(wait=True, cancel_futures=True)
            return
    ds.to_zarr(path, mode="w", consolidated=False)


def _mark_complete(store: str, ds: Any) -> None:
    import zarr

    root = zarr.open_group(store, mode="r+")
    root.create_group(COMPLETE_MARKER, attributes={
        "writer": "avll.write_map", "complete": True,
        "variables": {str(k): [int(n) for n in v.shape] for k, v in ds.data_vars.items()},
    })


def _is_marked(store: str) -> bool:
    import zarr

    try:
        root = zarr.open_group(store, mode="r")
        g = root[COMPLETE_MARKER]
    except (KeyError, FileNotFoundError, ValueError, TypeError, OSError):
        return False
    return isinstance(g, zarr.Group) and g.attrs.get("complete") is True


def write_map(data: Any, path: str | os.PathLike[str], format: str | None = None) -> str:
    """Writes a labelled map, boundary or dataset to Zarr (a directory) or netCDF
    (``format`` from the suffix ``.zarr`` / ``.nc`` unless given), through a temporary
    name renamed into place. A Dask-backed map is streamed chunk by chunk. Returns
    the path.

    A Zarr store gets the completeness marker :data:`COMPLETE_MARKER` once every chunk
    is written, and :func:`open_map` refuses a store without it: write Zarr maps with
    this function rather than ``.to_zarr``, whose interrupted output opens as a
    complete map with the missing chunks read as 0 ("locally unstable"). On Ctrl-C
    (or any error) the temporary store is removed and an existing ``path`` is left as
    it was."""
    import xarray as xr

    from . import _atomic

    p = os.fspath(path)
    fmt = _format(p, format)
    if isinstance(data, xr.DataArray):
        ds = data.to_dataset(name=data.name or "data", promote_attrs=True)
    elif isinstance(data, xr.Dataset):
        ds = data
    else:
        raise ValueError(f"data: expected an xarray DataArray or Dataset, got {type(data)}")
    parent = os.path.dirname(os.path.abspath(p)) or "."
    is_zarr = fmt == "zarr"
    if is_zarr and os.path.exists(p) and not os.path.isdir(p):
        raise ValueError(f"path: {p} exists and is not a folder (a Zarr store is one)")
    tmp: str | None = None
    try:
        # a Ctrl-C while the temporary name is made is raised when the block ends, with
        # tmp known
        with _atomic.deferred_sigint():
            if is_zarr:
                tmp = tempfile.mkdtemp(prefix=".avll-", suffix=".zarr", dir=parent)
            else:
                fd, tmp = tempfile.mkstemp(prefix=".avll-", suffix=".nc", dir=parent)
                os.close(fd)
        if is_zarr:
            _to_zarr(ds, tmp)
            _mark_complete(tmp, ds)
        else:
            ds.to_netcdf(tmp, engine="h5netcdf")
        with _atomic.deferred_sigint():
            if is_zarr and os.path.isdir(p):
                shutil.rmtree(p)
            os.replace(tmp, p)
    except BaseException:
        if tmp is not None:
            with _atomic.deferred_sigint():
                if is_zarr:
                    _remove_tree(tmp)
                elif os.path.exists(tmp):
                    os.unlink(tmp)
        raise
    return p


def open_map(path: str | os.PathLike[str], format: str | None = None) -> Any:
    """Opens what :func:`write_map` wrote: a DataArray when the file holds one
    variable, else the Dataset (lazily for Zarr). A Zarr store without the
    completeness marker of :func:`write_map` (one written by ``.to_zarr``, or whose
    writing was interrupted) is refused with a ``ValueError``."""
    import xarray as xr

    p = os.fspath(path)
    fmt = _format(p, format)
    if fmt == "zarr":
        if not os.path.isdir(p):
            raise ValueError(f"path: {p} is not a Zarr store (no such folder)")
        if not _is_marked(p):
            raise ValueError(
                f"path: {p} has no completeness marker (the group {COMPLETE_MARKER!r}): it "
                "was not written by avll.write_map, or its writing was interrupted, so chunks "
                "may be missing (a missing chunk reads as 0, 'locally unstable'); write it "
                "again with avll.write_map"
            )
        ds = xr.open_zarr(p, consolidated=False)
    else:
        ds = xr.load_dataset(p, engine="h5netcdf")
    if len(ds.data_vars) == 1:
        (name,) = ds.data_vars
        da = ds[name]
        da.attrs.update(ds.attrs)
        return da
    return ds


# ---------------------------------------------------------------------------
# Distributed work
# ---------------------------------------------------------------------------


def local_client(n_workers: int = 2, threads_per_worker: int = 1, **kwargs: Any) -> Any:
    """A ``dask.distributed.Client`` on a new local cluster of ``n_workers`` worker
    processes (close it with ``client.close(); client.cluster.close()``). ``kwargs`` go
    to ``LocalCluster``: its own options or its workers' (``memory_limit``, ...); a
    keyword neither knows is a ``ValueError`` naming it (dask would hand it to every
    worker, which fails at start-up far from the call)."""
    import inspect

    from distributed import Client, LocalCluster, Nanny, Worker

    known = {n for c in (LocalCluster, Nanny, Worker)
             for n, p in inspect.signature(c.__init__).parameters.items()
             if n != "self" and p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL)}  # fmt: skip
    unknown = sorted(set(kwargs) - known)
    if unknown:
        raise ValueError(f"local_client: unknown keyword(s) {', '.join(unknown)} (not an option "
                         "of dask.distributed.LocalCluster or of its workers)")  # fmt: skip
    cluster = LocalCluster(
        n_workers=check_int(n_workers, "n_workers", min=1),
        threads_per_worker=check_int(threads_per_worker, "threads_per_worker", min=1),
        **({"processes": True, "dashboard_address": None} | kwargs),
    )
    return Client(cluster)


@contextmanager
def _client_scope(client: Any) -> Iterator[Any]:
    """The given client; for a scheduler address a client connected to it, or without
    ``client`` a local cluster's, each created and closed around the work."""
    if client is not None and not isinstance(client, str):
        yield client
        return
    from distributed import Client

    c = local_client() if client is None else Client(client)
    try:
        yield c
    finally:
        cluster = getattr(c, "cluster", None)
        c.close()
        if cluster is not None and client is None:
            cluster.close()


def _members(models: Any) -> tuple[list[str], list[LowerLevelModel]]:
    if isinstance(models, LowerLevelModel):
        models = [models]
    # a calibration with intervals (or its uncertainty): its resampled models
    if getattr(models, "uncertainty", None) is not None or (
            hasattr(models, "samples") and hasattr(models, "models")):
        models = models_from_bootstrap(models)
    if isinstance(models, Mapping):
        names, ms = [str(k) for k in models], list(models.values())
    else:
        ms = list(models)
        names = [f"{m.name}-{i}" for i, m in enumerate(ms)] if ms else []
    if not ms:
        raise ValueError("models: no models given")
    for m in ms:
        S._model(m)
    if len(set(names)) != len(names):
        raise ValueError("models: member names must be unique")
    return names, ms


def _sweep_task(
    model: LowerLevelModel, kg: np.ndarray, tg: np.ndarray, kv: np.ndarray, order: int | None,
    threads: int, reduce: str | None,
) -> Any:
    name, p = S._model(model)
    kg, tg, kv = (np.array(a, dtype=np.float64) for a in (kg, tg, kv))
    _block_memory(f"sweep: one map of {kg.size} kg x {tg.size} Tg x {kv.size} kv on a worker",
                  float(kg.size) * tg.size * kv.size, S._pade_arg(order), S._SPLIT_GRID)
    codes = _map_block(
        name, p, kg, tg, kv, S._pade_arg(order), threads, S.EXACT_BUDGET,
        block_info={None: {"array-location": [(0, kg.size), (0, tg.size), (0, kv.size)]}},
    )
    if reduce is None:
        return codes
    th = S.thresholds(codes, kg, tg, kv)
    return np.concatenate([th.kg_max, th.tg_min, [th.kv_last_stable, th.tg_min_overall]])


def sweep(
    models: Any,
    kg: Any,
    tg: Any,
    kv: Any,
    pade_orders: Sequence[int | None] = (PADE_ORDER,),
    *,
    client: Any = None,
    reduce: str | None = None,
    threads: int = 1,
) -> Any:
    """Stability maps of many models (e.g. the three of Table II, or parameter samples
    of one model) at several Padé orders, one task per (model, order) on a
    ``dask.distributed`` client: ``client`` (a Client or a scheduler address), or a
    local cluster of two worker processes made for the call.

    ``models`` is a list of model objects (members named ``<name>-<i>``) or a dict of
    name -> model. Returns an ``xarray.DataArray`` of codes with dims
    ``("member", "pade_order", "kg", "Tg", "kv")``; with ``reduce="thresholds"`` an
    ``xarray.Dataset`` of ``kg_max``, ``tg_min`` (per kv), ``kv_last_stable`` and
    ``tg_min_overall`` per member and order instead (the maps stay on the workers).
    Each map is the Rust kernel's, so results equal the single-process ones bit for
    bit."""
    import xarray as xr

    names, ms = _members(models)
    kg_a, tg_a, kv_a = S._axis("kg", kg), S._axis("tg", tg), S._axis("kv", kv)
    orders = [None if o is None else S._order(o) for o in pade_orders]
    if not orders:
        raise ValueError("pade_orders: no orders given")
    if reduce not in (None, "thresholds"):
        raise ValueError(f"reduce: must be None or 'thresholds', got {reduce!r}")
    threads = check_threads(threads)
    tasks = [(m, o) for m in ms for o in orders]
    points = float(kg_a.size) * tg_a.size * kv_a.size
    # one task's map on a worker, before any cluster is started or contacted
    _block_memory(f"sweep: one map of {kg_a.size} kg x {tg_a.size} Tg x {kv_a.size} kv",
                  points, 0 if None in orders else 1, S._SPLIT_GRID)
    if reduce is None:
        # the gathered maps and their stacked copy, here
        check_memory(2.0 * points * len(tasks),
                     f"sweep: {len(ms)} members x {len(orders)} orders x {points:.0f} points "
                     f"gathered and stacked (2 bytes per point)",
                     f"{S._SPLIT_GRID}, or pass reduce='thresholds'")
    with _client_scope(client) as c:
        futs = [
            c.submit(_sweep_task, m, kg_a, tg_a, kv_a, o, threads, reduce, pure=False)
            for m, o in tasks
        ]
        res = c.gather(futs)
    order_lab = ["exact" if o is None else str(o) for o in orders]
    coords: dict[str, Any] = {"member": names, "pade_order": order_lab}
    attrs = {"codes": S.CODE_MEANINGS,
             "models": ";".join(f"{n}={m.name}" for n, m in zip(names, ms, strict=True))}
    if reduce is None:
        arr = np.stack(res).reshape(len(ms), len(orders), kg_a.size, tg_a.size, kv_a.size)
        coords.update({"kg": kg_a, "Tg": tg_a, "kv": kv_a})
        return xr.DataArray(arr, dims=("member", "pade_order", *DIMS), coords=coords,
                            name="codes", attrs=attrs)
    arr = np.stack(res).reshape(len(ms), len(orders), -1)
    n = kv_a.size
    coords["kv"] = kv_a
    return xr.Dataset(
        {
            "kg_max": (("member", "pade_order", "kv"), arr[:, :, :n]),
            "tg_min": (("member", "pade_order", "kv"), arr[:, :, n : 2 * n]),
            "kv_last_stable": (("member", "pade_order"), arr[:, :, 2 * n]),
            "tg_min_overall": (("member", "pade_order"), arr[:, :, 2 * n + 1]),
        },
        coords=coords,
        attrs=attrs,
    )


def stability_probability(
    models: Any,
    kg: Any,
    tg: Any,
    kv: Any,
    pade_order: int | None = PADE_ORDER,
    *,
    chunks: Mapping[str, int] | None = None,
) -> Any:
    """Probability of (local and string) stability over parameter samples: the share
    of ``models`` (a list or mapping of models, e.g. :func:`models_from_bootstrap`; or
    a calibration with intervals, ``avll.calibrate(..., intervals=True)``, or its
    :class:`avll.Uncertainty`: its resampled models) whose map is stable at each
    point, as an ``xarray.DataArray`` (dims kg, Tg, kv) of float64.

    With ``chunks`` every sample's map is Dask-backed (:func:`map_dataset`) and the
    mean over samples is a lazy reduction computed on the current Dask scheduler or
    client, chunk by chunk (memory: one chunk per sample in flight); call
    ``.compute()`` or write it with :func:`write_map`."""
    import xarray as xr

    names, ms = _members(models)
    if chunks is None:
        kg_a, tg_a, kv_a = S._axis("kg", kg), S._axis("tg", tg), S._axis("kv", kv)
        points = float(kg_a.size) * tg_a.size * kv_a.size
        # every sample's map, its stable mask and their stacked copy; the float64 mean
        check_memory(points * (3.0 * len(ms) + 8.0),
                     f"stability_probability: {len(ms)} samples x {points:.0f} points",
                     "pass chunks= to reduce chunk by chunk, or split the grid",
                     per=3.0 * points, unit="samples")
    maps = [map_dataset(m, kg, tg, kv, pade_order, chunks=chunks) for m in ms]
    stacked = xr.concat([(mp == S.STABLE) for mp in maps], dim="member")
    prob = stacked.mean("member", dtype=np.float64)
    prob.name = "p_stable"
    prob.attrs = {
        "definition": "share of the parameter samples that are locally and string stable",
        "samples": len(ms),
        "pade_order": "exact" if pade_order is None else int(pade_order),
        "model": ms[0].name,
    }
    return prob


def _min_tg_task(model: LowerLevelModel, kw: dict[str, Any]) -> tuple[float, float, float]:
    e = S.min_stable_tg(model, **kw)
    return e.value, e.kg, e.kv


def min_stable_tg_samples(
    models: Any,
    kg_range: tuple[float, float] = S.MIN_TG_BOX["kg"],
    kv_range: tuple[float, float] = S.MIN_TG_BOX["kv"],
    pade_order: int | None = PADE_ORDER,
    *,
    client: Any = None,
    distributed: bool = True,
    tg_range: tuple[float, float] = S.MIN_TG_BOX["Tg"],
    threads: int = 1,
) -> Any:
    """The minimum stable Tg (:func:`avll.min_stable_tg`) of every parameter sample: a
    distribution rather than a number. Returns an ``xarray.Dataset`` over ``member``
    with ``tg_min``, ``kg`` and ``kv`` (where each infimum is approached) and the 5 %,
    50 % and 95 % quantiles of ``tg_min`` as attributes (NaN samples, where nothing is
    stable, are left out of the quantiles and counted in ``n_unstable``). Runs one
    task per sample on ``client`` (or a local cluster), or in this process with
    ``distributed=False``."""
    import xarray as xr

    names, ms = _members(models)
    kw = dict(kg_range=tuple(kg_range), kv_range=tuple(kv_range), pade_order=pade_order,
              tg_range=tuple(tg_range), threads=int(threads))
    if distributed:
        with _client_scope(client) as c:
            res = c.gather([c.submit(_min_tg_task, m, kw, pure=False) for m in ms])
    else:
        res = [_min_tg_task(m, kw) for m in ms]
    arr = np.array(res, dtype=np.float64).reshape(len(ms), 3)
    ok = np.isfinite(arr[:, 0])
    q = np.quantile(arr[ok, 0], [0.05, 0.5, 0.95]) if ok.any() else [math.nan] * 3
    attrs: dict[str, Any] = {
        "definition": "infimum of the stable Tg per parameter sample (min_stable_tg)",
        "kg_range": list(kg_range), "kv_range": list(kv_range), "tg_range": list(tg_range),
        "pade_order": "exact" if pade_order is None else int(pade_order),
        "n_unstable": int((~ok).sum()),
        "q05": float(q[0]), "q50": float(q[1]), "q95": float(q[2]),
    }
    return xr.Dataset(
        {"tg_min": ("member", arr[:, 0]), "kg": ("member", arr[:, 1]),
         "kv": ("member", arr[:, 2])},
        coords={"member": names}, attrs=attrs,
    )


def models_from_bootstrap(bs: Any) -> list[LowerLevelModel]:
    """The calibrated models of an :func:`avll.bootstrap` result (one per resample), of
    an :class:`avll.Uncertainty` or of a calibration with intervals."""
    unc = getattr(bs, "uncertainty", None)
    if unc is None and hasattr(bs, "samples") and hasattr(bs, "models"):
        unc = bs
    if unc is not None:
        return list(unc.models())
    results = getattr(bs, "results", None)
    if results is None:
        raise ValueError(f"bs: expected an avll.Bootstrap, got {type(bs).__name__}")
    return [r.model for r in results]


_PROBLEM_KW = ("bounds", "closed_loop", "upper_free", "weights", "init")
_RUN_KW = ("initial", "target")


def _problem_kw(kwargs: dict[str, Any]) -> dict[str, Any]:
    """The problem keywords of :func:`avll.calibrate_many` in ``kwargs``, with its
    defaults."""
    pk: dict[str, Any] = {"bounds": None, "closed_loop": False, "upper_free": (),
                          "weights": None, "init": "rest"}
    pk.update({k: kwargs[k] for k in _PROBLEM_KW if k in kwargs})
    return pk


def _calibrate_block(
    model: Any, runs: list[Any], block: list[tuple[int, list[Any]]], seed: int, threads: int,
    kwargs: dict[str, Any],
) -> list[Any]:
    """Problems ``k`` of :func:`avll.calibrate_many` (one start each), each with the seed
    that function gives it (``derive_seed(seed, k)``): a one-problem GA call with that
    seed and seed derivation off is the same GA run."""
    from dataclasses import replace

    from .calibration import _per_run, _problem, _result, _run, _subset_indices

    ga = {k: v for k, v in kwargs.items() if k not in _PROBLEM_KW + _RUN_KW}
    prob = _problem(model, runs, **_problem_kw(kwargs))
    out = []
    for k, sub in block:
        idx = _subset_indices(prob.runs, sub, k)
        s = _core.derive_seed(int(seed), k)
        raw = _run(
            prob, [idx], seed=s, derive_seeds=False, initial=kwargs.get("initial"),
            target=kwargs.get("target"), threads=threads, progress=False, desc="",
            options=ga,
        )[0]
        uniq = sorted(set(idx))
        rs = [prob.runs[i] for i in uniq]
        per_run = _per_run(raw, len(prob.runs))[uniq]
        res = _result(prob, raw, rs, s, per_run)
        out.append(replace(res, start_costs=(float(raw["f"]),)))
    return out


def calibrate_many_distributed(
    model: Any,
    runs: Sequence[Any],
    subsets: Sequence[Sequence[int | str]] | str = "per_run",
    *,
    client: Any = None,
    seed: int = 0,
    batch: int = 1,
    threads: int = 1,
    **kwargs: Any,
) -> list[Any]:
    """:func:`avll.calibrate_many` with the problems spread over a
    ``dask.distributed`` client (``client``: a Client or scheduler address; default a
    local cluster of two worker processes), ``batch`` problems per task. Problem
    ``k`` is calibrated with the seed :func:`avll.calibrate_many` gives it, so the
    results are those of ``avll.calibrate_many(..., starts=1)``: one start per problem
    (``starts`` other than 1 is refused). ``kwargs`` are those of
    :func:`avll.calibrate_many` (bounds, closed_loop, upper_free, weights, init,
    initial, target and GA options; no progress bar)."""
    from ._limits import check_seed
    from .calibration import _ga_kwargs, _ga_memory, _problem

    if check_int(kwargs.pop("starts", 1), "starts", min=1) != 1:
        raise ValueError("starts: not supported by calibrate_many_distributed")
    if kwargs.pop("progress", False):
        raise ValueError("progress: not supported by calibrate_many_distributed")
    seed = check_seed(seed)
    threads = check_threads(threads)
    batch = check_int(batch, "batch", min=1)
    runs = list(runs)
    if isinstance(subsets, str):
        if subsets != "per_run":
            raise ValueError(f"subsets: expected run lists or 'per_run', got {subsets!r}")
        subs: list[list[Any]] = [[i] for i in range(len(runs))]
    else:
        subs = [list(s) for s in subsets]
    if not subs:
        raise ValueError("subsets: no problems given")
    # here, before any cluster is contacted: every keyword known (a misspelt one is an
    # error, not a remote traceback or a silently ignored option), the problem valid,
    # and a task's populations within this machine's memory
    ga = _ga_kwargs({k: v for k, v in kwargs.items() if k not in _PROBLEM_KW + _RUN_KW})
    prob = _problem(model, runs, **_problem_kw(kwargs))
    _ga_memory(prob, min(batch, len(subs)), ga)
    items = list(enumerate(subs))
    blocks = [items[i : i + batch] for i in range(0, len(items), batch)]
    with _client_scope(client) as c:
        runs_f = c.scatter(runs, broadcast=True)
        futs = [
            c.submit(_calibrate_block, model, runs_f, b, seed, threads, kwargs,
                     pure=False)
            for b in blocks
        ]
        res = c.gather(futs)
    return [r for block in res for r in block]


def bootstrap_distributed(
    model: Any,
    runs: Sequence[Any],
    n: int | None = None,
    *,
    seed: int = 0,
    level: float = LEVEL,
    client: Any = None,
    batch: int = 10,
    threads: int = 1,
    method: str = "runs",
    block: float | None = None,
    **kwargs: Any,
) -> Any:
    """:func:`avll.bootstrap` with the resamples' refits spread over a
    ``dask.distributed`` client (``batch`` resamples per task; the calibration itself
    runs here): the same multiplicities (drawn from ``seed``) and the same refits, so
    the same :class:`avll.Uncertainty`. ``kwargs`` are those of :func:`avll.calibrate`
    (bounds, closed_loop, upper_free, weights, init, initial, target, starts and GA
    options; no progress bar)."""
    from ._limits import check_number, check_seed
    from .calibration import _calibrate, _problem
    from .uncertainty import Intervals, estimate

    n = check_int(Intervals.n if n is None else n, "n", min=2)
    level = check_number(level, "level")
    if not 0 < level < 1:
        raise ValueError(f"level: must be in (0, 1), got {level}")
    seed = check_seed(seed)
    threads = check_threads(threads)
    batch = check_int(batch, "batch", min=1)
    if kwargs.pop("progress", False):
        raise ValueError("progress: not supported by bootstrap_distributed")
    runs = list(runs)
    if not runs:
        raise ValueError("runs: no runs given")
    # the resample weights, as avll.bootstrap estimates them; the GA's own estimate
    # follows in the calibration
    check_memory(80.0 * n * len(runs), f"bootstrap_distributed: n={n} resamples x "
                 f"{len(runs)} runs", "use fewer resamples per call and pool the samples",
                 per=80.0 * len(runs), unit="resamples")
    opts = Intervals(n=n, level=float(level), method=method, block=block)
    pkw = _problem_kw(kwargs)
    ga = {k: v for k, v in kwargs.items() if k not in _PROBLEM_KW + _RUN_KW + ("starts",)}
    from .defaults import DEFAULT_STARTS

    res = _calibrate(model, runs, seed=seed, threads=threads, progress=False,
                     initial=kwargs.get("initial"), target=kwargs.get("target"),
                     starts=kwargs.get("starts", DEFAULT_STARTS), ga_options=ga, **pkw)
    prob = _problem(model, runs, **pkw)

    def refit(subsets: list[list[int]], x0: np.ndarray, atoms: list[list[int]],
              weights: list[np.ndarray], o: Any, th: int) -> list[dict[str, Any]]:
        out: list[dict[str, Any]] = []
        with _client_scope(client) as c:
            runs_f = c.scatter(runs, broadcast=True)
            for k, sub in enumerate(subsets):
                w = weights[k]
                futs = [c.submit(_refit_task, model, runs_f, pkw, sub, x0[k], atoms[k],
                                 w[i : i + batch], int(o.budget), float(o.step), str(o.refit),
                                 float(o.ftol), int(th), pure=False)
                        for i in range(0, w.shape[0], batch)]
                parts = c.gather(futs)
                merged: dict[str, Any] = {
                    key: np.concatenate([np.asarray(p[key]) for p in parts])
                    for key in ("x", "f", "f_x0", "evaluations", "done")}
                merged["f_full"] = parts[0]["f_full"]
                merged.update({k: int(sum(int(p[k]) for p in parts))
                               for k in ("rollouts", "cache_hits")})
                merged["interrupted"] = False
                out.append(merged)
        return out

    u = estimate(prob, [list(range(len(runs)))], [np.asarray(res.x)], opts, seed=seed,
                 threads=threads, refit=refit)
    return u[0]


def _refit_task(model: Any, runs: list[Any], pkw: dict[str, Any], sub: list[int],
                x0: np.ndarray, atoms: list[int], weights: np.ndarray, budget: int,
                step: float, method: str, ftol: float, threads: int) -> dict[str, Any]:
    """One task of the distributed refits: the resamples ``weights`` of one problem."""
    from .calibration import _problem

    prob = _problem(model, runs, **pkw)
    return dict(_core.refit_resamples(
        prob.cls.name, lower_bounds=prob.lower, upper_bounds=prob.upper, scale=prob.scale,
        problems=[sub], x0=np.array([[float(v) for v in np.ravel(x0)]], dtype=np.float64),
        atoms=[atoms],
        resample_weights=[np.array(weights, dtype=np.float64, order="C", copy=True)],
        budget=budget, step=step, method=method, ftol=ftol,
        threads=threads, **prob.kw)[0])
