"""avll.datasets and ``avll data``: the registry (against the manifest and the shared
files when present), and fetching from a local HTTP server on 127.0.0.1 serving files
the tests make (no internet): success, files already there verified and not fetched
(requests counted), a flat mirror (``base_url``), a wrong hash, a truncated transfer, a
missing file and Ctrl-C, each leaving no partial file."""

from __future__ import annotations

import csv
import hashlib
import http.server
import json
import os
import re
import signal
import threading
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import unquote

import pytest
from loader_helpers import DATA, NO_DATA

import avll.datasets as ds
from avll.cli import main

ROOT = Path(__file__).resolve().parents[1]
CONTRACT = ("openacc-astazero", "openacc-zalazone", "openacc-casale", "openacc-jrc-low-speed",
            "openacc-vicolungo", "openacc-cherasco", "carma", "astazero-c2art")
JRC_CAMPAIGN = {"openacc-zalazone": "ZalaZone", "openacc-casale": "Casale",
                "openacc-jrc-low-speed": "JRC low speed", "openacc-vicolungo": "Vicolungo",
                "openacc-cherasco": "Cherasco"}
SHARED_FOLDER = {"carma": DATA / "carma", "astazero-c2art": DATA / "openacc-astazero"}


def _sha(b: bytes) -> str:
    return hashlib.sha256(b).hexdigest()


def _strict(text: str) -> object:
    def bad(c: str) -> object:
        raise ValueError(f"non-strict JSON constant {c}")

    return json.loads(text, parse_constant=bad)


# ---------------------------------------------------------------------------
# the registry
# ---------------------------------------------------------------------------


def test_names_are_the_contract() -> None:
    assert ds.names() == CONTRACT


def test_every_dataset_says_origin_licence_citation_and_files() -> None:
    for name in ds.names():
        d = ds.info(name)
        assert d.name == name
        for text in (d.origin, d.url, d.source, d.licence, d.licence_url, d.citation,
                     d.citation_url, d.licence_short, d.cite_as):
            assert text.strip(), (name, d)
        assert d.url.startswith("https://") and d.citation_url.startswith("https://doi.org/")
        mirror = [f.mirror_name for f in d.files]
        assert len(set(mirror)) == len(mirror), f"{name}: two files share a mirror name"
        for f in d.files:
            assert re.fullmatch(r"[0-9a-f]{64}", f.sha256) and f.size > 0, (name, f)
            assert f.url.startswith("https://") and " " not in f.url, (name, f)
        assert json.dumps(d.to_dict(), allow_nan=False)
    assert ds.info("carma").citation_url == "https://doi.org/10.21949/1503647"
    for name in CONTRACT:
        if name != "carma":
            assert ds.info(name).citation_url == "https://doi.org/10.1016/j.trc.2021.103047"


def test_jrc_urls_and_pinned_commits() -> None:
    base = "https://jeodpp.jrc.ec.europa.eu/ftp/jrc-opendata/TransportExpData/JRCDBT0001/LATEST/"
    for name, campaign in JRC_CAMPAIGN.items():
        d = ds.info(name)
        assert d.licence.startswith("CC BY 4.0") and d.files
        assert {f.name for f in d.files} >= {"copyright.txt"}
        for f in d.files:
            assert unquote(f.url) == f"{base}{campaign}/{f.name}"
    assert ds.info("openacc-jrc-low-speed").url == base + "JRC%20low%20speed/"
    for f in ds.info("carma").files:
        assert f.url.startswith("https://raw.githubusercontent.com/licit-lab/vrt_analysis/"
                                "fcdc1b15ad9a/data/raw/carma/")
    for f in ds.info("astazero-c2art").files:
        assert f.url.startswith("https://raw.githubusercontent.com/yinglonghe/C2ART-OPT/"
                                "8d392d8138/")


def test_astazero_native_is_listed_but_not_fetchable(tmp_path: Path) -> None:
    d = ds.info("openacc-astazero")
    assert d.files == () and "not registered" in d.note
    with pytest.raises(ValueError, match="openacc-astazero.*not registered.*astazero-c2art"):
        ds.fetch("openacc-astazero", dest=tmp_path / "a")
    assert not (tmp_path / "a").exists()


def test_unknown_name_and_bad_arguments(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="unknown dataset 'nope'; known: openacc-astazero"):
        ds.info("nope")
    with pytest.raises(ValueError, match="unknown dataset"):
        ds.fetch("nope", dest=tmp_path)
    with pytest.raises(ValueError, match="base_url: 'file:///x' is not an http"):
        ds.fetch("carma", dest=tmp_path, base_url="file:///x")
    (tmp_path / "f").write_text("x")
    with pytest.raises(ValueError, match="dest: .*f exists and is not a folder"):
        ds.fetch("carma", dest=tmp_path / "f")


def test_registry_matches_the_manifest() -> None:
    manifest = DATA / "openacc-manifest.csv"
    if not manifest.is_file():
        pytest.skip(NO_DATA)
    with open(manifest, encoding="utf-8", newline="") as fh:
        rows = list(csv.DictReader(fh))
    for name, campaign in JRC_CAMPAIGN.items():
        want = {(r["file"], int(r["bytes"]), r["sha256"]) for r in rows
                if r["campaign"] == campaign}
        got = {(f.name, f.size, f.sha256) for f in ds.info(name).files}
        assert got == want, name
    # every campaign of the manifest is a dataset; AstaZero is not in it
    assert {r["campaign"] for r in rows} == set(JRC_CAMPAIGN.values())


def _shared_files(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("name", sorted(SHARED_FOLDER))
def test_redistributions_match_the_shared_files(name: str) -> None:
    folder = SHARED_FOLDER[name]
    if not folder.is_dir():
        pytest.skip(NO_DATA)
    shared = _shared_files(folder)
    reg = {f.name: f for f in ds.info(name).files}
    assert set(reg) == set(shared), name
    for n, data in shared.items():
        assert (len(data), _sha(data)) == (reg[n].size, reg[n].sha256), (name, n)


def test_jrc_shared_files_are_the_registered_ones() -> None:
    """The shared copies of the JRC campaigns are files of the registry (same hash); the
    one file the JRC's ZalaZone listing does not have is named."""
    folders = {"openacc-zalazone": DATA / "openacc-zalazone",
               "openacc-casale": DATA / "openacc-jrc" / "Casale",
               "openacc-jrc-low-speed": DATA / "openacc-jrc" / "JRC low speed"}
    if not all(f.is_dir() for f in folders.values()):
        pytest.skip(NO_DATA)
    unregistered = []
    for name, folder in folders.items():
        reg = {f.name: f.sha256 for f in ds.info(name).files}
        for p in sorted(folder.rglob("*")):
            if not p.is_file():
                continue
            if p.name in reg:
                assert _sha(p.read_bytes()) == reg[p.name], p
            else:
                unregistered.append(p.relative_to(DATA).as_posix())
    # handling_part22.csv is in the project's copy of ZalaZone but not in the JRC's listing
    assert unregistered == ["openacc-zalazone/no_ACC/handling_part22.csv"]


# ---------------------------------------------------------------------------
# a local HTTP server
# ---------------------------------------------------------------------------


class Server:
    """Serves ``files`` (URL path -> bytes) on 127.0.0.1; ``mode[path]`` changes how:
    ``"truncate"`` (Content-Length of the whole, half of the body, then close),
    ``"slow"`` (half of the body, then wait for :attr:`release`). Unknown paths get 404.
    Every GET is counted in :attr:`hits`. Stops itself after ``limit`` seconds."""

    def __init__(self, limit: float = 60.0) -> None:
        self.files: dict[str, bytes] = {}
        self.mode: dict[str, str] = {}
        self.hits: Counter[str] = Counter()
        self.release = threading.Event()
        self.first_half_sent = threading.Event()
        server = self

        class Handler(http.server.BaseHTTPRequestHandler):
            timeout = 20

            def do_GET(self) -> None:  # noqa: N802 - http.server's name
                path = unquote(self.path)
                server.hits[path] += 1
                body = server.files.get(path)
                if body is None:
                    self.send_error(404, "not here")
                    return
                mode = server.mode.get(path, "")
                self.send_response(200)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                if mode in ("truncate", "slow"):
                    self.wfile.write(body[: len(body) // 2])
                    self.wfile.flush()
                    server.first_half_sent.set()
                    if mode == "slow":
                        server.release.wait(15)
                    self.close_connection = True
                    return
                self.wfile.write(body)

            def log_message(self, *a: object) -> None:
                pass

        self.httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.httpd.daemon_threads = True
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}"
        self.thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)
        self.timer = threading.Timer(limit, self.httpd.shutdown)
        self.timer.daemon = True

    def __enter__(self) -> Server:
        self.thread.start()
        self.timer.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release.set()
        self.timer.cancel()
        self.httpd.shutdown()
        self.httpd.server_close()
        self.thread.join(10)


@pytest.fixture
def server(monkeypatch: pytest.MonkeyPatch) -> Iterator[Server]:
    for var in ("NO_PROXY", "no_proxy"):  # a proxy from the environment must not intercept
        monkeypatch.setenv(var, "127.0.0.1,localhost")
    with Server() as s:
        yield s


CONTENT = {"a.csv": b"t,v\n0,1\n" * 500, "sub/b.csv": b"x,y\n1,2\n" * 300,
           "c d.txt": b"notes with a space in the name\n"}


def _dataset(monkeypatch: pytest.MonkeyPatch, srv: Server, name: str = "test-set",
             base: str = "/src") -> ds.Dataset:
    """A dataset of the three CONTENT files, served by ``srv`` under ``base``."""
    files = []
    for n, body in CONTENT.items():
        srv.files[f"{base}/{n}"] = body
        files.append(ds.DatasetFile(n, len(body), _sha(body),
                                    f"{srv.url}{base}/{n.replace(' ', '%20')}"))
    d = ds.Dataset(name=name, title="test", origin="tests", url=srv.url + base + "/",
                   source="tests", licence="none", licence_url="https://example.org/l",
                   citation="none", citation_url="https://doi.org/10.0/none",
                   licence_short="none", cite_as="none", files=tuple(files))
    monkeypatch.setitem(ds._REGISTRY, name, d)
    return d


def _listing(folder: Path) -> list[str]:
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file())


def test_fetch_downloads_and_verifies(server: Server, monkeypatch: pytest.MonkeyPatch,
                                      tmp_path: Path) -> None:
    _dataset(monkeypatch, server)
    dest = tmp_path / "d"
    got = ds.fetch("test-set", dest=dest, progress=False)
    assert got == dest
    assert _listing(dest) == sorted(CONTENT)
    for n, body in CONTENT.items():
        assert (dest / n).read_bytes() == body
    assert server.hits == Counter({f"/src/{n}": 1 for n in CONTENT})
    # again: every file verified, nothing requested
    r = ds.fetch_report("test-set", dest=dest, progress=False)
    assert r.status == {n: "verified" for n in CONTENT}
    assert sum(server.hits.values()) == 3


def test_present_files_are_verified_not_fetched(server: Server,
                                                monkeypatch: pytest.MonkeyPatch,
                                                tmp_path: Path) -> None:
    _dataset(monkeypatch, server)
    dest = tmp_path / "d"
    (dest / "sub").mkdir(parents=True)
    (dest / "a.csv").write_bytes(CONTENT["a.csv"])                   # right
    (dest / "sub" / "b.csv").write_bytes(CONTENT["sub/b.csv"][:-1] + b"X")  # same size, other hash
    r = ds.fetch_report("test-set", dest=dest, progress=False)
    assert r.status == {"a.csv": "verified", "sub/b.csv": "replaced", "c d.txt": "downloaded"}
    assert server.hits == Counter({"/src/sub/b.csv": 1, "/src/c d.txt": 1})
    assert (dest / "sub" / "b.csv").read_bytes() == CONTENT["sub/b.csv"]


def test_base_url_is_a_flat_mirror(server: Server, monkeypatch: pytest.MonkeyPatch,
                                   tmp_path: Path) -> None:
    d = _dataset(monkeypatch, server, base="/nowhere")
    for n in CONTENT:  # the source is gone; the mirror has the files flat
        del server.files[f"/nowhere/{n}"]
        server.files[f"/mirror/{Path(n).name}"] = CONTENT[n]
    assert [f.mirror_name for f in d.files] == ["a.csv", "b.csv", "c d.txt"]
    dest = ds.fetch("test-set", dest=tmp_path / "m", base_url=server.url + "/mirror/",
                    progress=False)
    assert _listing(dest) == sorted(CONTENT)
    assert server.hits == Counter({"/mirror/a.csv": 1, "/mirror/b.csv": 1,
                                   "/mirror/c d.txt": 1})


def test_default_folder_is_the_cache_or_avll_data_dir(server: Server,
                                                      monkeypatch: pytest.MonkeyPatch,
                                                      tmp_path: Path) -> None:
    _dataset(monkeypatch, server)
    monkeypatch.setenv("AVLL_DATA_DIR", str(tmp_path / "cache"))
    assert ds.cache_dir() == tmp_path / "cache"
    assert ds.fetch("test-set", progress=False) == tmp_path / "cache" / "test-set"
    monkeypatch.delenv("AVLL_DATA_DIR")
    assert ds.cache_dir().name == "avll"


def _no_partial(dest: Path, allowed: set[str]) -> None:
    """Only ``allowed`` files (complete, verified) in ``dest``: no temporary file."""
    assert set(_listing(dest)) == allowed if dest.exists() else not allowed


@pytest.mark.parametrize("fault", ["wrong hash", "truncated", "missing"])
def test_a_failed_file_is_a_clear_error_and_leaves_nothing(
        fault: str, server: Server, monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    _dataset(monkeypatch, server)
    path = "/src/sub/b.csv"
    if fault == "wrong hash":
        server.files[path] = CONTENT["sub/b.csv"].replace(b"2", b"3")
        why = "SHA-256 is not the registered"
    elif fault == "truncated":
        server.mode[path] = "truncate"
        why = "the transfer failed"
    else:
        del server.files[path]
        why = "HTTP 404"
    dest = tmp_path / "d"
    url = f"{server.url}{path}"
    with pytest.raises(ds.DownloadError) as e:
        ds.fetch("test-set", dest=dest, progress=False)
    msg = str(e.value)
    assert "dataset 'test-set'" in msg and "file 'sub/b.csv'" in msg and url in msg, msg
    assert why in msg, msg
    assert isinstance(e.value, OSError)
    _no_partial(dest, {"a.csv"})  # the file before it is complete; nothing of b.csv
    # the CLI: exit 2, one line naming the file
    assert main(["data", "fetch", "test-set", "--dest", str(dest), "-q"]) == 2
    _no_partial(dest, {"a.csv"})


def test_no_server_is_a_clear_error(server: Server, monkeypatch: pytest.MonkeyPatch,
                                    tmp_path: Path) -> None:
    import socket

    _dataset(monkeypatch, server)
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    base = f"http://127.0.0.1:{port}/m"
    with pytest.raises(ds.DownloadError, match=rf"dataset 'test-set': file 'a.csv' from "
                       rf"{re.escape(base)}/a.csv: the transfer failed"):
        ds.fetch("test-set", dest=tmp_path / "d", base_url=base, progress=False)
    _no_partial(tmp_path / "d", set())


def test_ctrl_c_leaves_no_partial_file(server: Server, monkeypatch: pytest.MonkeyPatch,
                                       tmp_path: Path, sigint_handler: None) -> None:
    _dataset(monkeypatch, server)
    server.mode["/src/a.csv"] = "slow"
    main_thread = threading.main_thread().ident
    assert main_thread is not None

    def interrupt() -> None:
        if server.first_half_sent.wait(10):
            signal.pthread_kill(main_thread, signal.SIGINT)

    t = threading.Thread(target=interrupt, daemon=True)
    t.start()
    dest = tmp_path / "d"
    with pytest.raises(KeyboardInterrupt):
        ds.fetch("test-set", dest=dest, progress=False)
    t.join(10)
    server.release.set()
    assert dest.is_dir() and _listing(dest) == []


@pytest.mark.parametrize("mode", ["log", "bar"])
def test_progress(mode: str, server: Server, monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                  capsys: pytest.CaptureFixture[str]) -> None:
    _dataset(monkeypatch, server)
    ds.fetch("test-set", dest=tmp_path / "d", progress=mode)
    err = capsys.readouterr().err
    assert "3 of 3 files to download" in err and "[1/3] a.csv" in err
    assert "3 files in" in err and "3 downloaded" in err
    assert ("100%" in err) == (mode == "bar")  # the bar (tqdm) only in bar mode
    ds.fetch("test-set", dest=tmp_path / "d", progress=False)
    assert capsys.readouterr().err == ""


# ---------------------------------------------------------------------------
# the command line
# ---------------------------------------------------------------------------


def test_cli_list_info_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "list.json"
    assert main(["data", "list", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    for name in CONTRACT:
        assert name in text
    got = _strict(out.read_text())
    assert isinstance(got, dict)
    assert [d["name"] for d in got["datasets"]] == list(CONTRACT)
    assert main(["data", "info", "carma", "--json", str(tmp_path / "i.json")]) == 0
    text = capsys.readouterr().out
    assert "https://doi.org/10.21949/1503647" in text and "data9.csv" in text
    info = _strict((tmp_path / "i.json").read_text())
    assert isinstance(info, dict) and len(info["files"]) == 5 and info["fetchable"]
    assert main(["data", "info", "openacc-astazero"]) == 0
    assert "not registered" in capsys.readouterr().out


def test_cli_fetch(server: Server, monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                   capsys: pytest.CaptureFixture[str]) -> None:
    _dataset(monkeypatch, server)
    dest, rep = tmp_path / "d", tmp_path / "r.json"
    assert main(["data", "fetch", "test-set", "--dest", str(dest), "-q",
                 "--json", str(rep)]) == 0
    assert capsys.readouterr().out.strip() == str(dest)
    got = _strict(rep.read_text())
    assert isinstance(got, dict) and got["downloaded"] == 3 and got["verified"] == 0
    assert main(["data", "fetch", "test-set", "--dest", str(dest), "-q"]) == 0
    assert sum(server.hits.values()) == 3
    assert main(["data", "fetch", "openacc-astazero", "--dest", str(tmp_path / "z")]) == 2
    assert "not registered" in capsys.readouterr().err
    assert main(["data", "fetch", "test-set", "--base-url", "file:///x", "--dest",
                 str(tmp_path / "y")]) == 2
    assert "--base-url: " in capsys.readouterr().err


def test_fetch_on_the_shared_copy_only_verifies() -> None:
    """``fetch(name, dest=<the shared copy>)`` verifies every file and downloads nothing
    (the docs' examples rely on it; the shared folder is read-only)."""
    folder = DATA / "carma"
    if not folder.is_dir():
        pytest.skip(NO_DATA)
    before = {p: p.stat().st_mtime_ns for p in folder.iterdir()}
    r = ds.fetch_report("carma", dest=folder, base_url="http://127.0.0.1:9/none",
                        progress=False)
    assert set(r.status.values()) == {"verified"}
    assert {p: p.stat().st_mtime_ns for p in folder.iterdir()} == before


# ---------------------------------------------------------------------------
# the docs
# ---------------------------------------------------------------------------


def test_docs_table_is_current() -> None:
    path = ROOT / "docs" / "_generated" / "datasets.md"
    text = path.read_text(encoding="utf-8")  # a stamp, then the table (docs/gen)
    assert text.startswith("<!-- generated by `python -m docs.gen --only datasets`")
    assert text.endswith("\n\n" + ds.markdown_table().rstrip("\n") + "\n"), (
        "docs/_generated/datasets.md is stale: python -m docs.gen --only datasets")


def test_docs_page_names_every_dataset() -> None:
    page = (ROOT / "docs" / "data.md").read_text(encoding="utf-8")
    assert "```{include} _generated/datasets.md" in page
    for name in CONTRACT:
        assert f"`{name}`" in page, name
    assert "avll data fetch" in page and "https://doi.org/10.1016/j.trc.2021.103047" in page
    assert "\ndata\n" in (ROOT / "docs" / "index.md").read_text(encoding="utf-8")  # toctree


def test_docs_field_data_examples_do_not_need_the_projects_folder() -> None:
    """Every Python example of the docs that reads ../shared/data gets its folder from
    avll.datasets.fetch (which only verifies when the folder is already complete)."""
    docs = ROOT / "docs"
    for page in sorted(docs.rglob("*.md")):
        if {"_build", "_generated"} & set(page.relative_to(docs).parts):
            continue
        for block in re.findall(r"^```python\n(.*?)^```", page.read_text(encoding="utf-8"),
                                re.S | re.M):
            for line in block.splitlines():
                if "shared/data" in line:
                    assert "fetch(" in line, f"{page.relative_to(ROOT)}: {line.strip()}"


def test_skip_reason_says_how_to_get_the_data() -> None:
    assert "avll data fetch" in NO_DATA and "docs/data.md" in NO_DATA
    assert os.fspath(DATA) in NO_DATA
