"""avll.progress: one display per stage; log lines (no escape codes) when stderr is
not a terminal; the count never overruns and a finished stage ends at 100 %."""

from __future__ import annotations

import io
import re

import pytest

import avll
from avll.progress import Progress, resolve_mode

_ESC = re.compile(r"\x1b|\r")


class _NotTty(io.StringIO):
    def isatty(self) -> bool:
        return False


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_modes() -> None:
    assert resolve_mode(True, _NotTty()) == "log"
    assert resolve_mode("auto", _Tty()) == "bar"
    assert resolve_mode(False) == "none" and resolve_mode(None) == "none"
    assert resolve_mode("log", _Tty()) == "log"
    with pytest.raises(ValueError, match="progress"):
        resolve_mode("loud")


def test_log_lines_are_plain_rate_limited_and_end_at_100() -> None:
    f = _NotTty()
    p = Progress(300, "calibrate", unit="gen", mode="auto", file=f, interval=3600.0)
    for i in range(1, 60):
        p.advance_to(i)  # converges early at 59 of 300
    p.close(complete=True)
    text = f.getvalue()
    lines = text.splitlines()
    assert _ESC.search(text) is None
    assert len(lines) == 2  # start and end: the 58 updates inside the interval are silent
    assert lines[0].startswith("avll: calibrate: started 0%")
    assert lines[-1].startswith("avll: calibrate: done 100% (300/300 gen)")


def test_log_lines_appear_once_per_interval() -> None:
    f = _NotTty()
    p = Progress(10, "map", mode="log", file=f, interval=0.0)
    for i in range(1, 11):
        p.advance_to(i)
    p.close()
    # start, one per step short of the total, and the end
    assert len(f.getvalue().splitlines()) == 1 + 9 + 1


def test_never_overruns_and_never_goes_back() -> None:
    p = Progress(100, "x", mode="none")
    p.update(70)
    p.update(70)
    assert p.n == 100
    p.advance_to(10)
    assert p.n == 100


def test_interrupted_stage_stops_where_it_was() -> None:
    f = _NotTty()
    with pytest.raises(KeyboardInterrupt), Progress(10, "x", mode="log", file=f,
                                                   interval=3600.0) as p:
        p.advance_to(4)
        raise KeyboardInterrupt
    assert "stopped at 40% (4/10" in f.getvalue().splitlines()[-1]


def test_none_prints_nothing() -> None:
    f = _NotTty()
    p = Progress(10, "x", mode="none", file=f)
    p.advance_to(5)
    p.write("message")
    p.close()
    assert f.getvalue() == ""


def test_bar_mode_finishes_at_total() -> None:
    f = _Tty()
    p = Progress(300, "calibrate", unit="gen", mode="auto", file=f)
    p.advance_to(21)
    p.close(complete=True)
    assert "300/300" in f.getvalue()


def test_calibration_converging_early_ends_at_100(monkeypatch: pytest.MonkeyPatch,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    """The GA stops long before max_generations (stall): the log still ends at 100 %."""
    import sys

    monkeypatch.setattr(sys, "stderr", _NotTty())
    runs = avll.synth.paper_experiment(avll.PAPER_TABLE_II["first"], runs=(3, 4),
                                       duration=30.0, seed=1)
    res = avll.calibrate("first", runs, seed=0, progress="auto", max_generations=2000,
                         starts=1)
    text = sys.stderr.getvalue()
    assert res.generations < 2000
    assert _ESC.search(text) is None
    last = [ln for ln in text.splitlines() if ln.startswith("avll: ")][-1]
    assert "done 100% (2000/2000 gen)" in last, text


def test_cli_quiet_silences_progress(tmp_path, capsys: pytest.CaptureFixture[str]) -> None:
    from avll.cli import main

    data = tmp_path / "runs.csv"
    assert main(["synth", "--out", str(data), "--duration", "20", "--model", "first"]) == 0
    capsys.readouterr()
    assert main(["calibrate", str(data), "--models", "first", "--max-generations", "5",
                 "--starts", "1", "-q"]) == 0
    assert "avll: " not in capsys.readouterr().err
    assert main(["calibrate", str(data), "--models", "first", "--max-generations", "5",
                 "--starts", "1", "--progress", "log"]) == 0
    err = capsys.readouterr().err
    assert "avll: calibrate" in err and _ESC.search(err) is None


@pytest.mark.skipif(not hasattr(__import__("signal"), "SIGINT") or __import__("os").name != "posix",
                    reason="needs SIGINT delivery")
def test_a_ctrl_c_lost_in_a_destructor_is_raised_at_the_next_progress_update(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A SIGINT handled while a ``__del__`` runs is printed as "ignored" by Python and
    the work would go on; under the ``avll`` command's latch the next progress update
    raises it (the race that once let an interrupted ``avll reproduce`` finish)."""
    import os
    import signal
    import sys

    from avll import _sigint

    ignored: list[type[BaseException] | None] = []
    monkeypatch.setattr(sys, "unraisablehook", lambda u: ignored.append(u.exc_type))

    if signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        pytest.skip("the test runner replaced Python's SIGINT handler")

    class Swallows:
        def __del__(self) -> None:
            os.kill(os.getpid(), signal.SIGINT)
            sum(range(10_000))  # the handler runs here; its exception is ignored

    with _sigint.latched():
        p = Progress(10, "x", mode="none")
        Swallows()  # deleted at once
        assert ignored == [KeyboardInterrupt]  # Python ignored it ...
        with pytest.raises(KeyboardInterrupt):
            p.update()  # ... the latch raises it again
        with pytest.raises(KeyboardInterrupt):
            Progress(1, "y", mode="none")  # and at every update until delivered
        _sigint.clear()
        p.update()
    # Outside the command: Python's handler is back, nothing latched.
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    _sigint.check()


@pytest.mark.skipif(not hasattr(__import__("signal"), "SIGINT") or __import__("os").name != "posix",
                    reason="needs SIGINT delivery")
def test_the_command_does_not_print_a_ctrl_c_python_ignored_and_delivers_it(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """In the ``avll`` command's process a Ctrl-C that lands in a weakref callback or a
    ``__del__`` (importlib's module-lock callback during an import, once in CI) is not
    printed as "Exception ignored ... Traceback": it is latched and delivered by the next
    check (the command checks once more before committing its outputs). Other
    unraisable exceptions still reach the previous hook."""
    import os
    import signal
    import sys
    import threading

    from avll import _sigint

    if threading.current_thread() is not threading.main_thread():
        pytest.skip("signal handlers can only be set in the main thread")
    # the command's own handlers are set here and the runner's put back after (so the
    # test also runs under pytest-xdist, whose workers replace Python's handler)
    previous = signal.getsignal(signal.SIGINT)
    seen: list[type[BaseException] | None] = []
    monkeypatch.setattr(sys, "unraisablehook", lambda u: seen.append(u.exc_type))
    monkeypatch.setattr(_sigint, "console", True)  # as in `avll ...` after at_startup()

    class Swallows:
        def __del__(self) -> None:
            os.kill(os.getpid(), signal.SIGINT)
            sum(range(10_000))  # the handler runs here; its exception is ignored

    class Fails:
        def __del__(self) -> None:
            raise ValueError("not a Ctrl-C")

    signal.signal(signal.SIGINT, _sigint.quiet_exit)
    try:
        _sigint.command_starts()
        assert signal.getsignal(signal.SIGINT) is _sigint.handler
        Swallows()
        assert seen == []  # not printed ...
        assert _sigint.interrupted()
        with pytest.raises(KeyboardInterrupt):
            _sigint.check()  # ... but delivered
        Fails()
        assert seen == [ValueError]
        _sigint._restore_unraisable()
        assert sys.unraisablehook is not _sigint._quiet_unraisable
    finally:
        signal.signal(signal.SIGINT, previous)
        _sigint.clear()
        _sigint._restore_unraisable()
