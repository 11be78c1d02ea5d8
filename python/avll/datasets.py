"""Field data by name: where each dataset comes from, its licence, the paper to cite, and
every file with its size and SHA-256, fetched into a local folder and checked by hash.

>>> import avll.datasets as ds
>>> ds.names()                                   # doctest: +SKIP
('openacc-astazero', 'openacc-zalazone', ..., 'carma', 'astazero-c2art')
>>> ds.info("carma").licence                     # doctest: +SKIP
'US federal government work (public domain in the United States)'
>>> folder = ds.fetch("carma")                   # doctest: +SKIP

:func:`fetch` works like pooch (which it uses for the transfer): every file goes to a
temporary name in the destination folder, its SHA-256 is checked, and only then is it
renamed to its final name; a wrong hash, a truncated transfer, a missing file (HTTP 404)
or Ctrl-C leave no partial file behind, and the error names the dataset, the file and the
URL. Files already in the folder with the right size and hash are verified, not fetched
again; a file with another hash is replaced by a verified download.

Where the files go: ``dest`` when given, else ``<cache>/<name>`` where ``<cache>`` is
the environment variable :data:`ENV_DATA_DIR` (``AVLL_DATA_DIR``) when set, else the
per-user cache folder (``pooch.os_cache("avll")``, e.g. ``~/.cache/avll`` on Linux).

Mirrors and proxies: ``base_url=B`` downloads every file from ``B + "/" + <file name>``
(a flat folder holding the dataset's files, e.g. a copy on an institute's server); an
HTTP(S) proxy is taken from the usual ``HTTPS_PROXY`` / ``HTTP_PROXY`` / ``NO_PROXY``
environment variables.

The datasets (``info(name)`` says the same, with links):

* ``openacc-zalazone``, ``openacc-casale``, ``openacc-jrc-low-speed``,
  ``openacc-vicolungo``, ``openacc-cherasco``: the JRC OpenACC campaigns, every file of
  the campaign folder as the JRC publishes it on its open-data server (one flat folder:
  data files, the campaign's notes, vehicle specifications, ``copyright.txt``);
  CC BY 4.0; cite Makridis et al. (2021).
* ``openacc-astazero``: the AstaZero campaign of the same server. Its file list is not
  registered (no hashes are known to avll), so :func:`fetch` refuses it with an
  explanation; the AstaZero files the project reads are ``astazero-c2art``.
* ``carma``: the FHWA CARMA platoon tests (July 2018), reduced CSVs as redistributed in
  licit-lab/vrt_analysis at a pinned commit; US federal government work; cite Tiernan et
  al. (2019).
* ``astazero-c2art``: the OpenACC AstaZero platoon and free-flow files as processed by the
  JRC and redistributed in yinglonghe/C2ART-OPT at a pinned commit (MIT licence for the
  repository; cite Makridis et al. (2021) for the data), arranged as ``platoon/`` and
  ``freeflow/`` (the folders :func:`avll.io.read_runs` reads with
  ``format="openacc-astazero"``).
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field, replace
from pathlib import Path, PurePosixPath
from typing import Any
from urllib.parse import quote

from ._atomic import _sha256
from ._dataset_files import FILES as _FILES

__all__ = [
    "ENV_DATA_DIR",
    "Dataset",
    "DatasetFile",
    "DownloadError",
    "FetchResult",
    "cache_dir",
    "fetch",
    "fetch_report",
    "info",
    "markdown_table",
    "names",
]

#: Environment variable naming the folder in which :func:`fetch` keeps the datasets
#: (one sub-folder per dataset) when no ``dest`` is given.
ENV_DATA_DIR = "AVLL_DATA_DIR"

#: Seconds without data after which a transfer is abandoned (requests' read timeout).
TIMEOUT = 60.0

#: The JRC open-data server's folder of the OpenACC database (one sub-folder per campaign).
JRC_OPENACC = "https://jeodpp.jrc.ec.europa.eu/ftp/jrc-opendata/TransportExpData/JRCDBT0001/LATEST"
#: The OpenACC database's page in the JRC data catalogue.
JRC_CATALOGUE = "https://data.jrc.ec.europa.eu/dataset/9702c950-c80f-4d2f-982f-44d06ea0009f"

OPENACC_PAPER = ("Makridis, M., Mattas, K., Anesiadou, A., Ciuffo, B. (2021). OpenACC. An open "
                 "database of car-following experiments to study the properties of commercial "
                 "ACC systems. Transportation Research Part C 125, 103047.")
OPENACC_DOI = "https://doi.org/10.1016/j.trc.2021.103047"
CARMA_REPORT = ("Tiernan et al. (2019). CARMA Testing and Evaluation of Research Mobility "
                "Applications. U.S. Department of Transportation, Federal Highway "
                "Administration.")
CARMA_DOI = "https://doi.org/10.21949/1503647"

CC_BY = "CC BY 4.0 (Creative Commons Attribution 4.0 International; see copyright.txt)"
CC_BY_URL = "https://creativecommons.org/licenses/by/4.0/"

#: The pinned commits of the two GitHub redistributions (as recorded with the project's
#: copies of the files; abbreviated ids, which GitHub resolves).
CARMA_REPO, CARMA_COMMIT = "licit-lab/vrt_analysis", "fcdc1b15ad9a"
C2ART_REPO, C2ART_COMMIT = "yinglonghe/C2ART-OPT", "8d392d8138"
_RAW = "https://raw.githubusercontent.com"


@dataclass(frozen=True)
class DatasetFile:
    """One file of a dataset: ``name`` its path inside the dataset folder (``/``
    separated), ``size`` in bytes, ``sha256`` (hex), ``url`` where :func:`fetch`
    downloads it from by default."""

    name: str
    size: int
    sha256: str
    url: str

    @property
    def mirror_name(self) -> str:
        """The file's name in a flat mirror folder (``base_url``): its last component."""
        return PurePosixPath(self.name).name


@dataclass(frozen=True)
class Dataset:
    """What is known of one dataset (see :func:`info`). ``files`` is empty when the
    file list is not registered (``note`` says why); ``url`` is where the files are
    published, ``source`` the pinned origin in words."""

    name: str
    title: str
    origin: str
    url: str
    source: str
    licence: str
    licence_url: str
    citation: str
    citation_url: str
    licence_short: str
    cite_as: str
    files: tuple[DatasetFile, ...] = ()
    note: str = ""
    references: tuple[tuple[str, str], ...] = field(default=())

    @property
    def size(self) -> int:
        """Bytes of all the files."""
        return sum(f.size for f in self.files)

    def to_dict(self) -> dict[str, Any]:
        """The dataset as plain JSON-ready values (files as a list of dicts)."""
        return {
            "name": self.name, "title": self.title, "origin": self.origin, "url": self.url,
            "source": self.source, "licence": self.licence, "licence_url": self.licence_url,
            "citation": self.citation, "citation_url": self.citation_url,
            "references": [{"text": t, "url": u} for t, u in self.references],
            "note": self.note, "size": self.size, "fetchable": bool(self.files),
            "files": [{"name": f.name, "size": f.size, "sha256": f.sha256, "url": f.url}
                      for f in self.files],
        }


class DownloadError(OSError):
    """A file of a dataset could not be fetched or did not verify (wrong SHA-256, a
    truncated transfer, HTTP error, network failure). The message names the dataset,
    the file and the URL; no partial file is left in the destination."""


@dataclass(frozen=True)
class FetchResult:
    """What :func:`fetch_report` did: the dataset's ``folder`` and, per file, one of
    ``"verified"`` (already there with the right hash), ``"downloaded"`` or
    ``"replaced"`` (there with another hash, replaced by a verified download)."""

    name: str
    folder: Path
    status: dict[str, str]

    def count(self, what: str) -> int:
        """How many files have status ``what``."""
        return sum(1 for s in self.status.values() if s == what)


def _files(name: str, base: str) -> tuple[DatasetFile, ...]:
    """The registered files of dataset ``name`` (none when not registered), each
    downloaded from its path in the source folder ``base``."""
    return tuple(DatasetFile(n, size, sha, f"{base}/{quote(src or n)}")
                 for n, size, sha, src in _FILES.get(name, ()))


def _jrc(name: str, campaign: str, when: str, place: str) -> Dataset:
    """A JRC OpenACC campaign; ``when`` (country, year) goes into the title, ``place``
    into the origin."""
    base = f"{JRC_OPENACC}/{quote(campaign)}"
    return Dataset(
        name=name, title=f"OpenACC {campaign} ({when}), the JRC's native files",
        origin="JRC OpenACC database (European Commission, Joint Research Centre), campaign "
        f"{place}: commercial ACC cars in platoons, GNSS trajectories",
        url=base + "/",
        source=f"the JRC open-data server, folder LATEST/{campaign}/ of the OpenACC "
        "database (JRCDBT0001), every file of the campaign folder as published",
        licence=CC_BY, licence_url=CC_BY_URL, citation=OPENACC_PAPER, citation_url=OPENACC_DOI,
        licence_short="CC BY 4.0", cite_as="Makridis et al. 2021", files=_files(name, base),
        references=(("JRC data catalogue: OpenACC", JRC_CATALOGUE),),
    )


def _registry() -> dict[str, Dataset]:
    reg = [
        replace(
            _jrc("openacc-astazero", "AstaZero", "Sweden, 2019",
                 "AstaZero test track, Sweden, July 2019"),
            source="the JRC open-data server, folder LATEST/AstaZero/ of the OpenACC database",
            note="The file list of this campaign is not registered: avll knows no names, "
            "sizes or SHA-256 of the JRC's AstaZero folder, so it cannot fetch and verify "
            "it. Download the campaign folder from the JRC server yourself (its url), or "
            "use 'astazero-c2art' (the AstaZero platoon and free-flow files the project "
            "reads, from a pinned redistribution, checked by hash).",
        ),
        _jrc("openacc-zalazone", "ZalaZone", "Hungary, 2019",
             "ZalaZone test track, Hungary, October 2019"),
        _jrc("openacc-casale", "Casale", "Italy, 2020",
             "Ispra - Casale Monferrato public motorway, Italy, October 2020"),
        _jrc("openacc-jrc-low-speed", "JRC low speed", "Italy, 2020",
             "JRC Ispra site roads, Italy, September 2020"),
        _jrc("openacc-vicolungo", "Vicolungo", "Italy", "Vicolungo, Italy"),
        _jrc("openacc-cherasco", "Cherasco", "Italy", "Cherasco, Italy"),
        Dataset(
            name="carma",
            title="FHWA CARMA CACC platoon tests (July 2018, 5 Cadillac SRX)",
            origin="US DOT / FHWA CARMA platform testing: per vehicle the speed commanded by "
            "the CARMA upper level, the measured wheel speed and CAN acceleration, 10 Hz; "
            "reduced CSVs and the data dictionary",
            url=f"https://github.com/{CARMA_REPO}/tree/{CARMA_COMMIT}/data/raw/carma",
            source=f"GitHub {CARMA_REPO} at commit {CARMA_COMMIT}, folder data/raw/carma "
            "(data-elements.xlsx is that folder's 'Data Elements.xlsx')",
            licence="US federal government work (public domain in the United States)",
            licence_url="https://www.usa.gov/government-copyright",
            citation=CARMA_REPORT, citation_url=CARMA_DOI,
            licence_short="US federal work", cite_as="Tiernan et al. 2019",
            files=_files("carma", f"{_RAW}/{CARMA_REPO}/{CARMA_COMMIT}/data/raw/carma"),
            references=((f"{CARMA_REPO}", f"https://github.com/{CARMA_REPO}"),),
        ),
        Dataset(
            name="astazero-c2art",
            title="OpenACC AstaZero platoon and free-flow files (C2ART-OPT redistribution)",
            origin="JRC OpenACC database, AstaZero test track (Sweden, 4 July 2019), as "
            "processed by the JRC: 5-car platoons (1-D position, Doppler speed, "
            "acceleration, spacing, 10 Hz), labels, road grade, free-flow ACC cruises "
            "with their set speed",
            url=f"https://github.com/{C2ART_REPO}/tree/{C2ART_COMMIT}/Data/ASTAZERO",
            source=f"GitHub {C2ART_REPO} at commit {C2ART_COMMIT}: platoon/ holds "
            "Data/ASTAZERO/Exp/PyData/*.csv, Exp/Slope.csv and Exp/CarIDs.xlsx; freeflow/ "
            "holds Data/ASTAZERO/ExpFreeFlow/PyData/*.csv; LICENSE-C2ART-OPT is the "
            "repository's LICENSE",
            licence="MIT licence of the C2ART-OPT repository (LICENSE-C2ART-OPT); the data "
            "are the JRC's OpenACC data (CC BY 4.0): credit the JRC and cite the OpenACC "
            "paper",
            licence_url=f"https://github.com/{C2ART_REPO}/blob/{C2ART_COMMIT}/LICENSE",
            citation=OPENACC_PAPER, citation_url=OPENACC_DOI,
            licence_short="MIT (repository); data CC BY 4.0", cite_as="Makridis et al. 2021",
            files=_files("astazero-c2art", f"{_RAW}/{C2ART_REPO}/{C2ART_COMMIT}"),
            references=((f"{C2ART_REPO}", f"https://github.com/{C2ART_REPO}"),
                        ("JRC data catalogue: OpenACC", JRC_CATALOGUE)),
        ),
    ]
    return {d.name: d for d in reg}


_REGISTRY = _registry()


def names() -> tuple[str, ...]:
    """The names of the registered datasets, in a fixed order."""
    return tuple(_REGISTRY)


def info(name: str) -> Dataset:
    """Everything known of dataset ``name``: origin, URL, licence, citation, and its files
    with size and SHA-256 (:class:`Dataset`). A ``ValueError`` lists the known names."""
    if not isinstance(name, str) or name not in _REGISTRY:
        raise ValueError(f"name: unknown dataset {name!r}; known: {', '.join(_REGISTRY)}")
    return _REGISTRY[name]


def cache_dir() -> Path:
    """The folder holding the datasets fetched without ``dest``: ``$AVLL_DATA_DIR`` when
    set (and not empty), else the per-user cache folder ``pooch.os_cache("avll")``."""
    env = os.environ.get(ENV_DATA_DIR, "").strip()
    if env:
        return Path(env).expanduser()
    import pooch

    return Path(pooch.os_cache("avll"))


def _mb(n: int) -> str:
    return f"{n / 1e6:.1f} MB"


def fetch(name: str, *, dest: str | os.PathLike[str] | None = None,
          base_url: str | None = None, progress: Any = True) -> Path:
    """Dataset ``name`` in a local folder, laid out as listed by :func:`info` (the JRC
    campaigns one flat folder as published); returns the folder.

    Files already in the folder with the registered size and SHA-256 are verified, not
    downloaded; the others are downloaded to a temporary name, checked, and renamed.
    Raises ``ValueError`` for an unknown name or a dataset whose files are not
    registered, :class:`DownloadError` (an ``OSError``) naming the dataset, the file and
    the URL when a download fails or does not verify; nothing partial is left behind.

    Parameters
    ----------
    name : str
        The dataset, one of :func:`names`.
    dest : path, optional
        The folder (created if needed); default ``<cache_dir()>/<name>``.
    base_url : str, optional
        Download every file from ``base_url + "/" + <file name>`` (a flat mirror
        folder) instead of the dataset's own URLs.
    progress : bool or str
        ``True`` (a bar on a terminal, a line per file otherwise), ``False``, or one of
        ``"auto"``, ``"bar"``, ``"log"``, ``"none"`` (see :mod:`avll.progress`).
    """
    return fetch_report(name, dest=dest, base_url=base_url, progress=progress).folder


def fetch_report(name: str, *, dest: str | os.PathLike[str] | None = None,
                 base_url: str | None = None, progress: Any = True) -> FetchResult:
    """:func:`fetch`, returning what was done per file (:class:`FetchResult`)."""
    from .progress import messages, resolve_mode

    ds = info(name)
    if not ds.files:
        raise ValueError(f"dataset {name!r} cannot be fetched: {ds.note} ({ds.url})")
    if base_url is not None:
        if not isinstance(base_url, str) or not base_url.strip():
            raise ValueError(f"base_url: expected a URL such as https://host/folder, got "
                             f"{base_url!r}")
        scheme = base_url.split("://", 1)[0].lower() if "://" in base_url else ""
        if scheme not in ("http", "https", "ftp"):
            raise ValueError(f"base_url: {base_url!r} is not an http://, https:// or ftp:// "
                             "URL")
    mode = resolve_mode(progress)
    say = messages(f"avll data {name}", mode)
    folder = Path(dest).expanduser() if dest is not None else cache_dir() / name
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"dest: {folder} exists and is not a folder")

    status: dict[str, str] = {}
    todo: list[DatasetFile] = []
    for f in ds.files:
        path = folder.joinpath(*PurePosixPath(f.name).parts)
        if path.is_dir():
            raise ValueError(f"dest: {path} is a folder where dataset {name!r} has the file "
                             f"{f.name!r}")
        if path.is_file() and path.stat().st_size == f.size and _sha256(path) == f.sha256:
            status[f.name] = "verified"
        else:
            status[f.name] = "replaced" if path.is_file() else "downloaded"
            todo.append(f)
    if todo:
        total = sum(f.size for f in todo)
        say(f"{len(todo)} of {len(ds.files)} files to download ({_mb(total)}) into {folder}")
    for i, f in enumerate(todo, 1):
        url = f.url if base_url is None else base_url.rstrip("/") + "/" + quote(f.mirror_name)
        if status[f.name] == "replaced":
            say(f"{f.name}: present with another SHA-256, downloading a verified copy")
        say(f"[{i}/{len(todo)}] {f.name} ({_mb(f.size)}) from {url}")
        _download(ds.name, f, url, folder, bar=(mode == "bar"))
    done = FetchResult(name=ds.name, folder=folder, status=status)
    say(f"{len(ds.files)} files in {folder}: {done.count('verified')} already there and "
        f"verified, {done.count('downloaded')} downloaded, {done.count('replaced')} replaced")
    return done


def _download(dataset: str, f: DatasetFile, url: str, folder: Path, *, bar: bool) -> None:
    """One file through pooch: a temporary file in the destination folder, the SHA-256
    checked, then renamed; pooch removes the temporary file on any error or Ctrl-C."""
    import pooch
    import requests

    path = folder.joinpath(*PurePosixPath(f.name).parts)
    where = f"dataset {dataset!r}: file {f.name!r} from {url}"
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OSError(e.errno, f"{where}: cannot create the folder {path.parent} "
                      f"({e.strerror})") from None
    logger = pooch.get_logger()
    level = logger.level
    logger.setLevel(logging.WARNING)  # avll says what it downloads; pooch need not
    downloader = _HTTPDownload(bar) if url.lower().startswith(("http://", "https://")) \
        else None
    try:
        pooch.retrieve(url, known_hash=f"sha256:{f.sha256}", fname=path.name,
                       path=path.parent, downloader=downloader, progressbar=bar)
    except requests.HTTPError as e:
        code = e.response.status_code if e.response is not None else "?"
        raise DownloadError(f"{where}: HTTP {code} ({_reason(e)}); nothing was written"
                            ) from None
    except requests.RequestException as e:
        raise DownloadError(f"{where}: the transfer failed ({_reason(e)}); nothing was "
                            "written (no partial file kept)") from None
    except ValueError as e:
        text = " ".join(str(e).split())
        if "hash" in text.lower():
            raise DownloadError(f"{where}: the downloaded file's SHA-256 is not the registered "
                                f"{f.sha256} (a corrupted or changed file); it was deleted, "
                                "nothing was written") from None
        raise DownloadError(f"{where}: {text}; nothing was written") from None
    except Exception as e:  # OSError, ftplib's errors, ...: never a traceback (not Ctrl-C)
        raise DownloadError(f"{where}: {type(e).__name__}: {_reason(e)}; nothing was "
                            "written") from None
    finally:
        logger.setLevel(level)


class _HTTPDownload:
    """pooch's downloader interface (``(url, output_file, pooch)``) over one
    ``requests`` session whose response is closed on every path: pooch's own
    HTTPDownloader leaves the connection of a failed, truncated or interrupted transfer
    open until the garbage collector finds it (a ResourceWarning at a random later
    point)."""

    def __init__(self, bar: bool) -> None:
        self.bar = bar

    def __call__(self, url: str, output_file: Any, _pooch: Any) -> None:
        import requests

        # The file is opened before the request is sent, so a Ctrl-C pressed once data
        # flows lands inside the ``with``, which closes it. Opened after the response,
        # such a Ctrl-C could fall between ``open`` returning and the ``with`` taking the
        # file, leaving it to the garbage collector. The same instant before the request
        # remains (pooch still removes the file; only a ResourceWarning could follow).
        with open(output_file, "w+b") as out, requests.Session() as session, \
                session.get(url, stream=True, timeout=TIMEOUT) as response:
            response.raise_for_status()
            progress = None
            if self.bar:
                from tqdm import tqdm

                progress = tqdm(total=int(response.headers.get("content-length", 0)),
                                ncols=79, unit="B", unit_scale=True, leave=True)
            try:
                for chunk in response.iter_content(chunk_size=1024):
                    out.write(chunk)
                    if progress is not None:
                        progress.update(len(chunk))
            finally:
                if progress is not None:
                    progress.close()


def _reason(e: BaseException) -> str:
    text = " ".join(str(e).split())
    return text[:300] if text else type(e).__name__


def markdown_table() -> str:
    """The table of datasets of the docs page "Getting the data" (name, files, size,
    licence, citation), generated from the registry; ``tests/test_datasets.py`` checks
    ``docs/_generated/datasets.md`` against it."""
    rows = ["| name | files | size | source | licence | cite |", "|---|---|---|---|---|---|"]
    for d in _REGISTRY.values():
        n = f"{len(d.files)}" if d.files else "not registered"
        size = _mb(d.size) if d.files else "—"
        rows.append(f"| `{d.name}` | {n} | {size} | [{_short_source(d)}]({d.url}) | "
                    f"[{d.licence_short}]({d.licence_url}) | [{d.cite_as}]({d.citation_url}) |")
    return "\n".join(rows) + "\n"


def _short_source(d: Dataset) -> str:
    if d.name == "carma":
        return f"{CARMA_REPO} @ {CARMA_COMMIT}"
    if d.name == "astazero-c2art":
        return f"{C2ART_REPO} @ {C2ART_COMMIT}"
    return "JRC open-data server, " + d.url.rstrip("/").rsplit("/", 1)[-1].replace("%20", " ")
