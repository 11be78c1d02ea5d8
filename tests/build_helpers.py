"""The digest of a checkout's Rust sources, computed as build.rs does for
``avll._core.SOURCE_DIGEST`` (FNV-1a, 64 bits, over ``rust/**/*.rs``, ``build.rs``,
``Cargo.toml`` and ``Cargo.lock``, in the byte order of their ``/``-separated paths,
each as ``path NUL content NUL``)."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_FNV_OFFSET = 0xCBF29CE484222325
_FNV_PRIME = 0x100000001B3
_MASK = (1 << 64) - 1


def _fnv1a(h: int, data: bytes) -> int:
    for b in data:
        h = ((h ^ b) * _FNV_PRIME) & _MASK
    return h


def source_digest(root: Path = ROOT) -> str:
    """The digest build.rs would embed for the sources under ``root``."""
    files = [p.relative_to(root).as_posix() for p in (root / "rust").rglob("*.rs")]
    files += [f for f in ("build.rs", "Cargo.toml", "Cargo.lock") if (root / f).is_file()]
    h = _FNV_OFFSET
    for rel in sorted(files, key=lambda s: s.encode()):
        h = _fnv1a(h, rel.encode() + b"\0")
        h = _fnv1a(h, (root / rel).read_bytes() + b"\0")
    return f"{h:016x}"
