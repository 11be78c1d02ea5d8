"""AstaZero in both folder layouts: the shared one
(``platoon/``, ``freeflow/``) and C2ART-OPT's (``Exp/PyData/*.csv`` with
``Exp/Slope.csv`` one folder up, ``ExpFreeFlow/PyData``), and the CLI's ``--slope``,
``--no-grade`` and ``--lap-length``."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from loader_helpers import ASTA, NO_DATA

from avll import DataError
from avll.cli import main
from avll.io import load_openacc_astazero, read_runs
from avll.io.openacc import grade_at, load_slope

pytestmark = pytest.mark.data

P7 = "ASta_040719_platoon7.csv"
FF = "ASta_040719_platoon7_30_270_V70.csv"


@pytest.fixture(scope="module")
def c2art(tmp_path_factory):
    """The C2ART-OPT layout built from the shared files (copies in a temp folder)."""
    if not ASTA.exists():
        pytest.skip(NO_DATA)
    root = tmp_path_factory.mktemp("c2art") / "Data" / "ASTAZERO"
    exp, ff = root / "Exp" / "PyData", root / "ExpFreeFlow" / "PyData"
    exp.mkdir(parents=True)
    ff.mkdir(parents=True)
    shutil.copy(ASTA / "platoon" / P7, exp)
    shutil.copy(ASTA / "platoon" / "Labels.csv", exp)
    shutil.copy(ASTA / "platoon" / "Slope.csv", root / "Exp")
    shutil.copy(ASTA / "freeflow" / FF, ff)
    shutil.copy(ASTA / "freeflow" / "FreeFlowStableParts.csv", ff)
    return root


def test_c2art_layout_reads_like_the_shared_layout(c2art):
    mine = read_runs(c2art, format="openacc-astazero")
    shared = {r.run_id: r for r in read_runs(ASTA, format="openacc-astazero")}
    assert [r.run_id for r in mine] == [f"ASta_040719_platoon7/v{i}-v{i + 1}"
                                        for i in range(1, 5)] + [FF[:-4]]
    for r in mine:
        ref = shared[r.run_id]
        np.testing.assert_array_equal(r.exo["grade"], ref.exo["grade"])
        np.testing.assert_array_equal(r.lead_x, ref.lead_x)


def test_slope_one_folder_up_and_given(c2art, tmp_path):
    f = c2art / "Exp" / "PyData" / P7
    runs = load_openacc_astazero(f)
    assert "grade" in runs[0].exo
    # a slope given explicitly wins; a profile of zeros gives zero grade
    z = tmp_path / "flat.csv"
    z.write_text("X,Y\n0,0\n1000,0\n5757.904,0\n")
    flat = load_openacc_astazero(f, slope=z)
    assert not np.any(flat[0].exo["grade"])
    assert load_openacc_astazero(f, grade=False)[0].exo == {}
    with pytest.raises(FileNotFoundError, match="nope.csv"):
        load_openacc_astazero(f, slope=tmp_path / "nope.csv")


def test_lap_length_option(c2art):
    f = c2art / "Exp" / "PyData" / P7
    slope = load_slope(c2art / "Exp" / "Slope.csv")
    r = load_openacc_astazero(f, lap_length=5000.0)[0]
    np.testing.assert_allclose(r.exo["grade"], grade_at(r.x, slope, lap_length=5000.0))
    default = load_openacc_astazero(f)[0]
    assert not np.allclose(r.exo["grade"], default.exo["grade"])
    with pytest.raises(ValueError, match="lap_length"):
        load_openacc_astazero(f, lap_length=-1.0)


def test_no_slope_found_is_a_data_error(tmp_path):
    if not ASTA.exists():
        pytest.skip(NO_DATA)
    shutil.copy(ASTA / "platoon" / P7, tmp_path)
    shutil.copy(ASTA / "platoon" / "Labels.csv", tmp_path)
    with pytest.raises(DataError, match="Slope.csv"):
        load_openacc_astazero(tmp_path / P7)
    assert len(load_openacc_astazero(tmp_path / P7, grade=False)) == 4


def test_cli_options(c2art, tmp_path, capsys):
    f = str(c2art / "Exp" / "PyData" / P7)
    rep = tmp_path / "r.json"
    assert main(["load", f, "--format", "openacc-astazero", "--no-grade",
                 "--json", str(rep)]) == 0
    assert main(["load", f, "--format", "openacc-astazero", "--lap-length", "5000",
                 "--slope", str(c2art / "Exp" / "Slope.csv")]) == 0
    capsys.readouterr()
    assert main(["load", f, "--format", "openacc-astazero", "--slope",
                 str(tmp_path / "missing.csv")]) == 2
    assert "--slope" in capsys.readouterr().err
    assert main(["load", f, "--format", "openacc-astazero", "--lap-length", "-3"]) == 2
    assert "--lap-length" in capsys.readouterr().err
    assert main(["load", f, "--format", "openacc-astazero", "--no-grade", "--lap-length",
                 "5000"]) == 2
    assert "conflicts with --no-grade" in capsys.readouterr().err
    assert main(["load", f, "--format", "carma", "--no-grade"]) == 2
    assert "only for --format openacc-astazero" in capsys.readouterr().err
    # the calibrate command takes the same options (a tiny GA budget)
    assert main(["calibrate", f, "--format", "openacc-astazero", "--no-grade", "--models",
                 "first", "--max-generations", "2", "--pop-size", "8", "--starts", "1",
                 "-q"]) == 0
    assert main(["calibrate", f, "--format", "canonical", "--no-grade", "-q"]) == 2
