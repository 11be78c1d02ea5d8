"""Atomic outputs: every file the library writes goes through this module.

Files: :func:`atomic_path` yields a temporary name beside the destination
(``.<name>.tmp-XXXXXX<suffix>``: writers that look at the suffix still work), flushed to
disk and renamed onto it (``os.replace``) when the block ends normally, removed otherwise
(an error, Ctrl-C): a reader sees the old file or the complete new one, never a truncated
one. :func:`write_text`, :func:`write_bytes`, :func:`write_json` (strict JSON, which
:func:`loads` reads back strictly), :func:`savefig`, :func:`to_csv` and
:func:`to_parquet` are built on it.

Folders: :func:`output_dir` stages a folder of outputs in a hidden folder inside it
(``.avll-tmp-XXXXXX``) and commits it when the block ends, Ctrl-C deferred: the old
``MANIFEST.json`` is removed first, every new file moved in, files of the old manifest
the new run did not write removed, and the new manifest (names, sizes, SHA-256) written
last. Interrupted before the commit, the folder is as it was; files the user put there
are never touched. :func:`read_manifest` checks a folder against its manifest.
"""

from __future__ import annotations

import contextlib
import contextvars
import hashlib
import json
import math
import os
import shutil
import signal
import tempfile
import threading
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

__all__ = [
    "MANIFEST", "atomic_path", "atomic_paths", "write_text", "write_bytes", "write_json",
    "json_safe", "dumps", "loads", "json_depth", "savefig", "figure_dpi", "figure_bytes",
    "to_csv", "to_parquet",
    "output_dir", "output_group", "read_manifest", "same_file", "check_not_inputs",
    "deferred_sigint",
]

#: Name of the manifest that marks a complete output folder.
MANIFEST = "MANIFEST.json"
#: Prefix of the hidden staging folder inside an output folder.
STAGING_PREFIX = ".avll-tmp-"


def _fsync_file(path: str | os.PathLike[str]) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_dir(path: str | os.PathLike[str]) -> None:
    with contextlib.suppress(OSError):  # e.g. Windows, where a folder cannot be opened
        _fsync_file(path)


# os.umask can only be read by setting it: done once, at import
_UMASK = os.umask(0o022)
os.umask(_UMASK)


@contextlib.contextmanager
def deferred_sigint() -> Iterator[None]:
    """Defers Ctrl-C (SIGINT) and SIGTERM for the duration of the block (main thread
    only); a signal received meanwhile acts afterwards: SIGINT raised as
    ``KeyboardInterrupt``, SIGTERM re-sent to the process (its default action ends it;
    the ``avll`` command's handler raises ``KeyboardInterrupt``)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    got: list[Any] = []
    try:
        old = signal.signal(signal.SIGINT, lambda s, f: got.append(s))
        old_term = signal.signal(signal.SIGTERM, lambda s, f: got.append(s))
    except ValueError:  # pragma: no cover - not the main interpreter
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)
        signal.signal(signal.SIGTERM, old_term)
        if signal.SIGTERM in got:
            signal.raise_signal(signal.SIGTERM)
        if signal.SIGINT in got and callable(old):
            old(signal.SIGINT, None)  # the default handler raises KeyboardInterrupt


@contextlib.contextmanager
def atomic_paths(*paths: str | os.PathLike[str]) -> Iterator[list[Path]]:
    """Yields one temporary path beside each of ``paths``; when the block ends normally
    they are flushed to disk and renamed onto ``paths`` one after the other with
    Ctrl-C deferred (the renames take microseconds), otherwise they are removed.
    Parent folders are created if needed."""
    dests = [Path(p) for p in paths]
    tmps: list[str] = []
    try:
        for dest in dests:
            if dest.is_dir():
                raise IsADirectoryError(f"{dest}: is a folder, expected a file name")
            try:
                # Ctrl-C deferred: the file exists only once `tmps` holds it (a Ctrl-C
                # between the two would leave it behind)
                with deferred_sigint():
                    dest.parent.mkdir(parents=True, exist_ok=True)
                    fd, tmp = tempfile.mkstemp(prefix=f".{dest.stem}.tmp-",
                                               suffix=dest.suffix, dir=dest.parent)
                    tmps.append(tmp)
                    os.close(fd)
            except OSError as e:
                raise OSError(e.errno, f"{dest}: cannot write here ({e.strerror})") from None
            os.chmod(tmp, 0o666 & ~_UMASK)
        yield [Path(t) for t in tmps]
        for t in tmps:
            _fsync_file(t)
        group = _GROUP.get()
        if group is not None and not any(
                part.startswith(STAGING_PREFIX) for d in dests for part in d.parts):
            # renamed with the group's other outputs when it ends (see output_group)
            group.append(("files", list(zip(tmps, dests, strict=True))))
            return
        with deferred_sigint():
            for t, dest in zip(tmps, dests, strict=True):
                os.replace(t, dest)
    except BaseException:
        for t in tmps:
            with contextlib.suppress(OSError):
                os.unlink(t)
        raise
    for d in {dest.parent for dest in dests}:
        _fsync_dir(d)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yields a temporary path beside ``path``; renames it onto ``path`` (after
    ``fsync``) when the block ends normally, removes it otherwise. The parent folder
    is created if needed."""
    with atomic_paths(path) as (tmp,):
        yield tmp


def write_bytes(path: str | os.PathLike[str], data: bytes) -> Path:
    """Writes ``data`` to ``path`` atomically; returns the path."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def write_text(path: str | os.PathLike[str], text: str, encoding: str = "utf-8") -> Path:
    """Writes ``text`` to ``path`` atomically; returns the path."""
    return write_bytes(path, text.encode(encoding))


def _non_finite(v: Any) -> bool:
    return isinstance(v, float) and not math.isfinite(v)


def _plain(v: Any) -> Any:
    """numpy scalars and arrays as Python values and lists (anything else unchanged)."""
    if type(v).__module__ == "numpy":
        import numpy as np

        if isinstance(v, np.ndarray):
            return v.tolist()
        if isinstance(v, np.generic):
            return v.item()
    return v


def json_safe(x: Any) -> Any:
    """``x`` made strict-JSON-ready -- the one helper every JSON output of avll goes
    through (:func:`dumps`, :func:`write_json`): numpy scalars and arrays become Python
    values and lists, tuples lists, keys strings; a non-finite float becomes ``None``
    with a reason beside it: in a dict, ``"<key>_note": "nan (not finite)"``; in a
    list held by a dict, one ``"<key>_note"`` saying which entries are null because
    they were not finite."""
    x = _plain(x)
    if isinstance(x, dict):
        out: dict[str, Any] = {}
        for k, v in x.items():
            v = _plain(v)
            if _non_finite(v):
                out[str(k)] = None
                out[f"{k}_note"] = f"{v} (not finite)"
            elif isinstance(v, (list, tuple)):
                items = [_plain(e) for e in v]
                bad = [i for i, e in enumerate(items) if _non_finite(e)]
                out[str(k)] = json_safe(items)
                if bad and f"{k}_note" not in x:
                    shown = ", ".join(str(i) for i in bad[:10]) + (", ..." if len(bad) > 10
                                                                    else "")
                    out[f"{k}_note"] = (f"null at {len(bad)} position(s) ({shown}): "
                                        "not finite (nan or inf)")
            else:
                out[str(k)] = json_safe(v)
        return out
    if isinstance(x, (list, tuple)):
        return [None if _non_finite(_plain(v)) else json_safe(v) for v in x]
    if _non_finite(x):
        return None
    return x


def dumps(obj: Any, *, indent: int | None = 2, default: Any = None) -> str:
    """Strict JSON text of ``obj`` after :func:`json_safe` (``allow_nan=False``: no
    ``NaN``/``Infinity`` tokens can appear)."""
    return json.dumps(json_safe(obj), indent=indent, allow_nan=False, default=default)


def loads(text: str, *, max_depth: int | None = None) -> Any:
    """The strict-JSON reader every JSON input of avll goes through (a calibration JSON
    for ``--from``, a canonical file's sidecar): ``text`` parsed as RFC 8259 JSON, a
    ``ValueError`` that says why otherwise -- a syntax error (with its line and
    column), a duplicated key, a ``NaN``/``Infinity`` token, an integer too long to
    convert, a document nested deeper than ``max_depth`` levels (or than the parser
    can follow)."""
    try:
        doc = json.loads(text, object_pairs_hook=_unique_keys, parse_constant=_not_a_number)
    except json.JSONDecodeError as e:
        raise ValueError(f"not valid JSON (line {e.lineno}, column {e.colno}: {e.msg})"
                         ) from None
    except RecursionError:
        raise ValueError(f"nested deeper than {max_depth} levels" if max_depth is not None
                         else "nested too deeply to parse") from None
    if max_depth is not None and json_depth(doc) > max_depth:
        raise ValueError(f"nested deeper than {max_depth} levels")
    return doc


def json_depth(x: Any) -> int:
    """Nesting depth of a parsed JSON value: 0 for a scalar, 1 for a flat object or
    array (iterative: no recursion limit)."""
    best, stack = 0, [(x, 1)]
    while stack:
        v, d = stack.pop()
        if isinstance(v, dict):
            best = max(best, d)
            stack.extend((w, d + 1) for w in v.values())
        elif isinstance(v, list):
            best = max(best, d)
            stack.extend((w, d + 1) for w in v)
    return best


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in pairs:
        if k in out:
            raise ValueError(f"duplicated key {k!r}")
        out[k] = v
    return out


def _not_a_number(word: str) -> float:
    raise ValueError(f"{word} is not a JSON number")


def write_json(path: str | os.PathLike[str], obj: Any, *, indent: int | None = 2,
               default: Any = None) -> Path:
    """Strict JSON of ``obj`` (:func:`dumps`: non-finite numbers become ``null`` with a
    note beside them) written atomically, with a final newline."""
    return write_text(path, dumps(obj, indent=indent, default=default) + "\n")


_DPI: contextvars.ContextVar[int | None] = contextvars.ContextVar("avll_dpi", default=None)


@contextlib.contextmanager
def figure_dpi(dpi: int | None) -> Iterator[None]:
    """Within the block, every :func:`savefig` writes raster figures at ``dpi`` dots per
    inch, whatever its caller asked for (the ``--dpi`` of the ``avll`` command); None
    changes nothing."""
    token = _DPI.set(dpi)
    try:
        yield
    finally:
        _DPI.reset(token)


def savefig(fig: Any, path: str | os.PathLike[str], **kw: Any) -> Path:
    """``fig.savefig`` to ``path`` atomically (the format from the suffix unless
    ``format=`` is given; the resolution from :func:`figure_dpi` when one is set)."""
    p = Path(path)
    if "format" not in kw and p.suffix:
        kw["format"] = p.suffix[1:].lower()
    if _DPI.get() is not None:
        kw["dpi"] = _DPI.get()
    with atomic_path(p) as tmp:
        fig.savefig(tmp, **kw)
    return p


def figure_bytes(fig: Any, fmt: str, **kw: Any) -> bytes:
    """The bytes of ``fig`` in format ``fmt`` (``png``, ``svg``, ``pdf``), at the
    resolution of :func:`figure_dpi` when one is set."""
    import io

    if _DPI.get() is not None:
        kw["dpi"] = _DPI.get()
    buf = io.BytesIO()
    fig.savefig(buf, format=fmt, **kw)
    return buf.getvalue()


def to_csv(df: Any, path: str | os.PathLike[str], **kw: Any) -> Path:
    """``DataFrame.to_csv`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        df.to_csv(tmp, **kw)
    return Path(path)


def to_parquet(df: Any, path: str | os.PathLike[str], **kw: Any) -> Path:
    """``DataFrame.to_parquet`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        df.to_parquet(tmp, **kw)
    return Path(path)


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _files(root: Path) -> list[str]:
    rels = [p.relative_to(root) for p in root.rglob("*") if p.is_file() and p.name != MANIFEST]
    return sorted(str(r).replace(os.sep, "/") for r in rels
                  if not any(part.startswith(STAGING_PREFIX) for part in r.parts))


def _old_manifest_files(dest: Path) -> list[str]:
    try:
        doc = loads((dest / MANIFEST).read_text(encoding="utf-8"))
        return [str(f) for f in doc.get("files", {})]
    except (OSError, ValueError, AttributeError):
        return []


@contextlib.contextmanager
def output_dir(path: str | os.PathLike[str], *, meta: dict[str, Any] | None = None
               ) -> Iterator[Path]:
    """Yields a temporary folder (hidden, inside ``path``) to write a folder of outputs
    into; commits it onto ``path`` with a manifest written last when the block ends
    normally (see the module doc); removes it otherwise. ``meta`` goes into the
    manifest."""
    dest = Path(path)
    if dest.exists() and not dest.is_dir():
        raise NotADirectoryError(f"{dest}: exists and is not a folder")
    created = not dest.exists()
    ok = deferred = False
    stage: Path | None = None
    try:
        try:
            # Ctrl-C deferred: the stage exists only once the cleanup below knows it (a
            # Ctrl-C between the two would leave it behind)
            with deferred_sigint():
                dest.mkdir(parents=True, exist_ok=True)
                stage = Path(tempfile.mkdtemp(prefix=STAGING_PREFIX, dir=dest))
        except OSError as e:
            raise OSError(e.errno, f"{dest}: cannot write here ({e.strerror})") from None
        yield stage
        group = _GROUP.get()
        if group is not None:
            # committed with the group's other outputs when it ends (see output_group)
            group.append(("folder", (stage, dest, dict(meta or {}), created)))
            deferred = True
        else:
            _commit(stage, dest, meta or {})
        ok = True
    finally:
        if stage is not None and not deferred:
            _drop_stage(stage, dest, created and not ok)


def _drop_stage(stage: Path, dest: Path, remove_dest: bool) -> None:
    shutil.rmtree(stage, ignore_errors=True)
    if remove_dest:
        with contextlib.suppress(OSError):
            dest.rmdir()  # only if still empty: a folder this run created


#: The outputs of the open :func:`output_group`: ("files", [(tmp, dest), ...]) and
#: ("folder", (stage, dest, meta, created)) entries, in the order they were written.
_GROUP: contextvars.ContextVar[list[tuple[str, Any]] | None] = contextvars.ContextVar(
    "avll_output_group", default=None)


@contextlib.contextmanager
def output_group() -> Iterator[None]:
    """Every output written in the block (files through :func:`atomic_paths` and its
    writers, folders through :func:`output_dir`) is committed as one unit when the
    block ends normally: all renames and folder commits run then, in the order the
    outputs were written, with Ctrl-C deferred; an error or a Ctrl-C inside the block
    removes every temporary file and staging folder, so the destinations stay as they
    were (never a new figure beside an old JSON). The ``avll`` command runs each
    sub-command in one group. Writes inside a staging folder are not deferred (the
    folder's own commit covers them)."""
    if _GROUP.get() is not None:  # nested: the outer group commits
        yield
        return
    pending: list[tuple[str, Any]] = []
    token = _GROUP.set(pending)
    ok = False
    try:
        yield
        ok = True
    finally:
        _GROUP.reset(token)
        if ok:
            _commit_group(pending)
        else:
            _abort_group(pending)


def _commit_group(pending: list[tuple[str, Any]]) -> None:
    done = 0
    with deferred_sigint():
        try:
            for kind, item in pending:
                done += 1
                if kind == "files":
                    for tmp, dest in item:
                        os.replace(tmp, dest)
                    for d in {dest.parent for _, dest in item}:
                        _fsync_dir(d)
                else:
                    stage, dest, meta, created = item
                    try:
                        _commit(stage, dest, meta)
                    finally:
                        _drop_stage(stage, dest, False)
        except BaseException:
            _abort_group(pending[done:])
            raise


def _abort_group(pending: list[tuple[str, Any]]) -> None:
    for kind, item in pending:
        if kind == "files":
            for tmp, _ in item:
                with contextlib.suppress(OSError):
                    os.unlink(tmp)
        else:
            stage, dest, _, created = item
            _drop_stage(stage, dest, created)


def _commit(stage: Path, dest: Path, meta: dict[str, Any]) -> None:
    new = _files(stage)
    doc = {"complete": True, **meta,
           "files": {f: {"bytes": (stage / f).stat().st_size, "sha256": _sha256(stage / f)}
                     for f in new}}
    for f in new:
        _fsync_file(stage / f)
    with deferred_sigint():
        old = _old_manifest_files(dest)
        with contextlib.suppress(FileNotFoundError):
            os.unlink(dest / MANIFEST)
        _fsync_dir(dest)
        for f in new:
            target = dest / f
            target.parent.mkdir(parents=True, exist_ok=True)
            os.replace(stage / f, target)
        for f in set(old).difference(new):
            with contextlib.suppress(OSError):
                (dest / f).unlink()
        write_json(dest / MANIFEST, doc)


def read_manifest(path: str | os.PathLike[str], *, verify: bool = True) -> dict[str, Any]:
    """The manifest of a complete output folder. Raises ``ValueError`` when the folder
    has none (an interrupted or foreign folder) or, with ``verify``, when a listed file
    is missing or differs from it."""
    d = Path(path)
    mp = d / MANIFEST
    try:
        doc = loads(mp.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ValueError(f"{d}: no {MANIFEST}: not a complete avll output folder "
                         "(interrupted, or written by something else)") from None
    except ValueError as e:
        raise ValueError(f"{mp}: {e}") from None
    if not isinstance(doc, dict) or doc.get("complete") is not True or not isinstance(
            doc.get("files"), dict):
        raise ValueError(f"{mp}: not an avll manifest")
    if verify:
        for f, info in doc["files"].items():
            p = d / f
            if not p.is_file():
                raise ValueError(f"{d}: {f} is listed in {MANIFEST} but missing")
            if p.stat().st_size != info.get("bytes") or _sha256(p) != info.get("sha256"):
                raise ValueError(f"{d}: {f} differs from {MANIFEST} (changed after the run)")
    return doc


def same_file(a: str | os.PathLike[str], b: str | os.PathLike[str]) -> bool:
    """Whether two paths name the same file (the same resolved path, or the same inode
    through a link)."""
    pa, pb = Path(a), Path(b)
    with contextlib.suppress(OSError):
        if pa.exists() and pb.exists():
            return os.path.samefile(pa, pb)
    try:
        return pa.resolve() == pb.resolve()
    except (OSError, RuntimeError):  # a symbolic link loop: compared as written (the
        # loaders refuse such a path with a clear error)
        return os.path.abspath(pa) == os.path.abspath(pb)


def check_not_inputs(outputs: Sequence[tuple[str, Any]], inputs: Sequence[tuple[str, Any]]
                     ) -> None:
    """Refuses (``ValueError`` naming both) an output that is the same file as an input
    (equal resolved paths, or the same inode through a link) or the same folder as an
    input folder. ``outputs`` / ``inputs`` are ``(label, path)`` pairs; ``None`` paths
    are skipped. Run before any computation."""
    ins = [(lab, Path(p)) for lab, p in inputs if p is not None]
    for olab, o in outputs:
        if o is None:
            continue
        op = Path(o)
        for ilab, ip in ins:
            if same_file(op, ip):
                raise ValueError(f"{olab}: {op} is the input {ilab} ({ip}); writing it would "
                                 "replace the input: choose another output name")
