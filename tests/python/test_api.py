"""The public API (``import capsmech``) and the CLI that wraps it: the contracts a notebook and a
lab's script rely on (issue 21, items 1, 4 and 5). The batch is the shipped example
data/examples/tube_batch_NH.csv (made by scripts/make_examples.py, NH, G_s 0.04 N/m)."""
from __future__ import annotations

import warnings
from pathlib import Path

import pandas as pd
import pytest

import capsmech
from capsmech.cli.main import build_parser, main
from capsmech.inversion.fitting import FLAG_CODES, TUBE_RESULT_UNITS

ROOT = Path(__file__).resolve().parents[2]
BATCH = ROOT / "data" / "examples" / "tube_batch_NH.csv"


@pytest.fixture(scope="module")
def tube_db():
    return capsmech.load_database("tube-paper")


@pytest.fixture(scope="module")
def capsules():
    return capsmech.read_measurements(BATCH)


def test_fit_tube_returns_a_dataframe_with_codes_reasons_and_units(capsules, tube_db):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", capsmech.OutsideDatabaseWarning)
        frame = capsmech.fit_tube(capsules, tube_db, laws=["NH", "GH_nu0.5"])
    assert isinstance(frame, pd.DataFrame)
    assert len(frame) == 2 * len(capsules)
    assert list(frame.columns) == list(TUBE_RESULT_UNITS)
    assert frame.attrs["units"]["G_s"] == "N/m"
    assert set(frame["flag"]) <= {""} | set(FLAG_CODES)
    # A flagged row says why in words and has no modulus; a fitted one has no reason.
    flagged = frame[frame["flag"] != ""]
    assert (flagged["reason"] != "").all()
    assert frame.loc[frame["flag"] == "", "reason"].eq("").all()
    # The batch is NH at 0.04 N/m: the NH fits hold it within 10 % (its noise, measured).
    nh = frame[(frame["law"] == "NH") & (frame["flag"] == "")]
    assert len(nh) >= len(capsules) // 2
    assert abs(nh["G_s"].median() / 0.04 - 1) < 0.1


def test_one_law_as_a_string_is_one_law_not_its_letters(capsules, tube_db):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", capsmech.OutsideDatabaseWarning)
        frame = capsmech.fit_tube(capsules[:3], tube_db, "NH")
    assert set(frame["law"]) == {"NH"}


def test_by_name_by_path_and_by_object_agree(capsules, tube_db):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", capsmech.OutsideDatabaseWarning)
        by_object = capsmech.fit_tube(capsules[:4], tube_db, "NH")
        by_name = capsmech.fit_tube(BATCH, "tube-paper", "NH").iloc[:4]
    pd.testing.assert_frame_equal(by_object, by_name.reset_index(drop=True))


def test_unknown_law_lists_the_valid_ones(capsules, tube_db):
    with pytest.raises(capsmech.CapsmechError, match=r"no law 'GH'.*valid laws: .*GH_nu0\.5"):
        capsmech.fit_tube(capsules, tube_db, "GH")


def test_a_database_of_the_other_flow_is_named_not_a_key_error(capsules):
    with pytest.raises(capsmech.CapsmechError, match="shear database; fit_tube needs a tube database"):
        capsmech.fit_tube(capsules, "shear-paper")


def test_capsules_without_a_value_warn_once_with_their_codes(capsules, tube_db):
    # GH nu_s 0 cannot reproduce every NH capsule's lengths: some rows have no value.
    with pytest.warns(capsmech.OutsideDatabaseWarning) as caught:
        frame = capsmech.fit_tube(capsules, tube_db, ["NH", "GH_nu0"])
    unfitted = int((frame["flag"] != "").sum())
    assert unfitted > 0
    assert len(caught) == 1
    assert str(caught[0].message).startswith(f"{unfitted} of {len(frame)} ")


def test_population_and_its_figure(capsules, tube_db):
    from matplotlib.figure import Figure

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", capsmech.OutsideDatabaseWarning)
        frame = capsmech.fit_tube(capsules, tube_db, ["NH", "GH_nu0.5"])
    verdict = capsmech.population(frame)
    table = capsmech.population_table(verdict)
    assert set(table["law"]) == set(verdict.drifts)
    assert table.attrs["units"]["G_s_mean"] == "N/m"
    figure = capsmech.plot_population(frame, verdict)
    assert isinstance(figure, Figure)
    assert figure.axes[0].get_ylabel() == "G_s [N/m]"


def test_database_repr_is_short(tube_db):
    assert len(repr(tube_db)) < 300


def test_the_cli_prints_units_and_writes_what_the_api_returns(tmp_path, capsys):
    out = tmp_path / "fit.csv"
    assert main(["fit-tube", str(BATCH), "--database", "tube-paper", "--law", "NH", "--out", str(out)]) == 0
    header = capsys.readouterr().out.splitlines()[0].split()
    assert "G_s" in header and "[N/m]" in header and "a_over_l" in header and "[1]" in header
    written = capsmech.read_results(out)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", capsmech.OutsideDatabaseWarning)
        api = capsmech.fit_tube(BATCH, "tube-paper", "NH")
    assert list(written["id"]) == list(api["id"])
    assert list(written["flag"]) == list(api["flag"])
    fitted = api["flag"] == ""
    assert (abs(written.loc[fitted, "G_s"] / api.loc[fitted, "G_s"] - 1) < 1e-5).all()


def test_the_cli_names_an_unknown_law_without_a_traceback(capsys):
    assert main(["fit-tube", str(BATCH), "--law", "GH"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("capsmech: error: --law:") and "GH_nu0.5" in err and "Traceback" not in err


def test_a_batch_no_law_can_fit_exits_non_zero(tmp_path, capsys):
    # Lengths no steady capsule of the database has (L_p close to L_z: a long, thin slug).
    batch = tmp_path / "outside.csv"
    lines = BATCH.read_text(encoding="utf-8").splitlines()
    header = next(line for line in lines if not line.startswith("#"))
    columns = [c.split(" [")[0] for c in header.split(",")]
    rows = [line.split(",") for line in lines if line and not line.startswith("#") and line != header][:3]
    iz, ip = columns.index("L_z"), columns.index("L_p")
    for row in rows:
        row[ip] = f"{0.99 * float(row[iz]):.6g}"
        if "contour" in columns:
            row[columns.index("contour")] = ""
    batch.write_text("\n".join([header] + [",".join(r) for r in rows]) + "\n", encoding="utf-8")
    assert main(["fit-tube", str(batch), "--law", "NH"]) == 1
    assert "no capsule" in capsys.readouterr().err


def test_developer_commands_sit_under_dev():
    parser = build_parser()
    jobs = parser._subparsers._group_actions[0].choices  # noqa: SLF001 (argparse has no public accessor)
    assert {"run-case", "kernel-version", "unlock-stale"}.isdisjoint(jobs)
    assert parser.parse_args(["dev", "unlock-stale", "."]).action == "unlock-stale"


def test_the_workflows_case_command_imports_no_user_job():
    """`capsmech dev run-case`, started once per database case, parses the developers' commands
    alone and imports neither pandas nor scipy nor matplotlib (1.2 s a process: more than most
    steady tube cases take in the kernel), nor does `import capsmech` (its names load on use)."""
    import subprocess
    import sys

    for argv in (["-m", "capsmech.cli", "dev", "run-case", "--help"], ["-c", "import capsmech"]):
        proc = subprocess.run([sys.executable, "-X", "importtime", *argv], capture_output=True, text=True, check=True)
        imported = {line.rsplit("|", 1)[-1].strip() for line in proc.stderr.splitlines()}
        assert {"pandas", "scipy", "matplotlib"}.isdisjoint(imported), argv


def test_law_is_repeatable_wherever_it_takes_several():
    parser = build_parser()
    for command in (["fit-tube", "x.csv"], ["fit-shear", "x.csv"], ["compare-methods"]):
        args = parser.parse_args([*command, "--law", "NH", "--law", "GH_nu0.5"])
        assert args.law == ["NH", "GH_nu0.5"], command


def test_extract_returns_the_capsules_of_the_shipped_film_with_units():
    """The rendered film data/examples/frames/capsule_NH.tif (scripts/make_example_frames.py):
    its truth file holds the lengths, velocity and tube radius it was drawn with; the film's
    TIFF metadata give the calibration, so none is passed."""
    import csv

    folder = ROOT / "data" / "examples" / "frames"
    with (folder / "truth.csv").open(encoding="utf-8") as stream:
        truth = next(csv.DictReader(line for line in stream if not line.startswith("#")))
    found = capsmech.extract(folder / "capsule_NH.tif")
    assert found.pixel_size_um == float(truth["pixel_size [um]"])
    assert found.frame_rate == float(truth["frame_rate [1/s]"])
    assert len(found.frames) == 20 and list(found.frames["index"]) == list(range(20))
    measured = found.capsules[found.capsules["flag"] == ""]
    assert len(measured) == 1
    row = measured.iloc[0]
    assert found.capsules.attrs["units"]["L_z"] == "um" and found.capsules.attrs["units"]["v_c"] == "mm/s"
    # Within two pixels (the membrane line's width) of the drawn lengths, 1 % of the velocity.
    pixel = found.pixel_size_um
    assert abs(row["L_z"] - float(truth["L_z [um]"])) < 2 * pixel
    assert abs(row["L_p"] - float(truth["L_p [um]"])) < 2 * pixel
    assert abs(row["tube_radius"] - float(truth["tube_radius [um]"])) < pixel
    assert abs(row["v_c"] / float(truth["v_c [mm/s]"]) - 1) < 0.01
    # The good frames are the film's measured ones: 20 less the 4 cut by the border and 1 blurred.
    assert row["good_frames"] == (found.frames["flag"] == "").sum() == 15


def test_extract_without_calibration_names_the_parameter(tmp_path):
    import imageio.v3 as iio
    import tifffile

    # The film's frames as PNG files: the same images, without the TIFF's calibration.
    for k, page in enumerate(tifffile.imread(ROOT / "data" / "examples" / "frames" / "capsule_NH.tif")[:5]):
        iio.imwrite(tmp_path / f"frame_{k}.png", page)
    with pytest.raises(capsmech.CapsmechError, match="^pixel_size: required"):
        capsmech.extract(str(tmp_path / "frame_*.png"))
    with pytest.raises(capsmech.CapsmechError, match="^frame_rate: required"):
        capsmech.extract(str(tmp_path / "frame_*.png"), pixel_size="0.6um")


def test_the_cli_shows_a_capsmech_warning_as_one_line():
    """What a notebook sees as an InputWarning, the command line prints as one line (a fresh
    interpreter: pytest records warnings in-process instead of showing them)."""
    import subprocess
    import sys

    spreadsheet = ROOT / "tests" / "python" / "data" / "spreadsheet" / "tube_excel.csv"
    run = subprocess.run([sys.executable, "-m", "capsmech.cli", "fit-tube", str(spreadsheet), "--law", "NH"],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    warned = [line for line in run.stderr.splitlines() if "warning" in line.lower()]
    assert warned == [f"capsmech: warning: {spreadsheet}:2: ignored column(s) not in the tube format: 'note'"]
