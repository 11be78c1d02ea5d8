"""``avll data``: the field data by name (:mod:`avll.datasets`).

* ``avll data list`` -- one line per dataset (name, files, size, licence);
* ``avll data info NAME`` -- origin, URLs, licence, citation and every file with its size
  and SHA-256;
* ``avll data fetch NAME [--dest DIR] [--base-url URL]`` -- download what is missing,
  verify everything, print the folder.

``--json PATH`` writes the same as strict JSON.
"""

from __future__ import annotations

import argparse
from typing import Any

from ._common import add_json, add_progress, declare_io


def _write_json(path: str | None, obj: Any) -> None:
    if path:
        from .. import _atomic

        _atomic.write_json(path, _atomic.json_safe(obj), indent=1)


def _list(args: argparse.Namespace) -> int:
    from ..datasets import info, names

    rows = [info(n) for n in names()]
    width = max(len(d.name) for d in rows)
    for d in rows:
        files = f"{len(d.files):3d} files {d.size / 1e6:7.1f} MB" if d.files \
            else "file list not registered"
        print(f"{d.name:<{width}}  {files}  {d.licence_short}  {d.title}")
    _write_json(args.json, {"datasets": [d.to_dict() for d in rows]})
    return 0


def _info(args: argparse.Namespace) -> int:
    from ..datasets import info

    d = info(args.name)
    print(f"{d.name}: {d.title}")
    print(f"  origin:   {d.origin}")
    print(f"  source:   {d.source}")
    print(f"  url:      {d.url}")
    print(f"  licence:  {d.licence} <{d.licence_url}>")
    print(f"  cite:     {d.citation} {d.citation_url}")
    for text, url in d.references:
        print(f"  see also: {text} <{url}>")
    if d.note:
        print(f"  note:     {d.note}")
    if d.files:
        print(f"  files:    {len(d.files)}, {d.size} bytes in all")
        for f in d.files:
            print(f"    {f.sha256}  {f.size:>10d}  {f.name}")
    _write_json(args.json, d.to_dict())
    return 0


def _fetch(args: argparse.Namespace) -> int:
    from ..datasets import fetch_report

    try:
        r = fetch_report(args.name, dest=args.dest, base_url=args.base_url,
                         progress=args.progress)
    except ValueError as e:  # the library names its arguments; the CLI its options
        msg = str(e)
        for arg, opt in (("base_url: ", "--base-url: "), ("dest: ", "--dest: ")):
            if msg.startswith(arg):
                raise ValueError(opt + msg[len(arg):]) from None
        raise
    print(r.folder)
    _write_json(args.json, {"name": r.name, "folder": str(r.folder), "files": r.status,
                            "verified": r.count("verified"),
                            "downloaded": r.count("downloaded"),
                            "replaced": r.count("replaced")})
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Registers ``avll data`` and its commands ``list``, ``info`` and ``fetch``."""
    from ..datasets import names

    known = names()
    p = sub.add_parser(
        "data", help="the field data by name: list, info, fetch (checked by SHA-256)",
        description="Field data by name: where each dataset comes from, its licence and "
        "the paper to cite, and every file with its size and SHA-256; 'fetch' downloads "
        "what is missing into a folder and verifies every file (see docs/data.md).")
    cmds = p.add_subparsers(dest="data_command", required=True, metavar="ACTION")

    q = cmds.add_parser("list", help="the datasets, one per line",
                        description="The registered datasets: name, files, size, licence.")
    add_json(q, "the registry (every dataset with its files)")
    declare_io(q, files=("json",))
    q.set_defaults(func=_list)

    q = cmds.add_parser("info", help="origin, licence, citation and files of one dataset",
                        description="Origin, URLs, licence, citation and every file (size, "
                        "SHA-256) of one dataset.")
    q.add_argument("name", metavar="NAME", choices=known,
                   help=f"the dataset (required): {', '.join(known)}")
    add_json(q, "the dataset's description")
    declare_io(q, files=("json",))
    q.set_defaults(func=_info)

    q = cmds.add_parser(
        "fetch", help="download a dataset into a folder, verified by SHA-256",
        description="Download the files of a dataset that are not already in the folder, "
        "check every file's SHA-256 (files already there with the right hash are not "
        "downloaded again) and print the folder. A failed or wrong download leaves no "
        "partial file. Proxies: the usual HTTPS_PROXY/HTTP_PROXY/NO_PROXY variables.")
    q.add_argument("name", metavar="NAME", choices=known,
                   help=f"the dataset (required): {', '.join(known)}")
    q.add_argument("--dest", default=None, metavar="DIR",
                   help="folder to fill (default: $AVLL_DATA_DIR/NAME, or the per-user "
                   "cache folder's avll/NAME)")
    q.add_argument("--base-url", default=None, metavar="URL",
                   help="download every file from URL/<file name> (a flat mirror folder) "
                   "instead of the dataset's own source (default: the source)")
    add_progress(q)
    add_json(q, "what was done per file (verified, downloaded, replaced)")
    declare_io(q, files=("json",))
    q.set_defaults(func=_fetch)
