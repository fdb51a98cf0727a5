"""Property-based fuzz tests of the readers of outside input (issue 25, item 5).

Each reader gets inputs that Hypothesis builds from a grammar of what the files hold (headers,
units, numbers of every size, separators, quotes, comments, encodings), raw bytes, and valid
files damaged (bytes flipped, cut short). The property is the same everywhere: the reader
either returns data that satisfy its documented guarantees, or refuses with its own error (a
``CapsmechError``; the kernel: exit 2 and one ``capsim: error:`` line) whose message names the
file. Anything else (an exception of another class, a signal, a hang) is a crash.

``make test`` runs a short campaign (``FAST``, about half a minute in all); ``make validate``
runs the long one (``pytest -m validate``, ``LONG`` examples each). With ``CAPSMECH_FUZZ_REPORT``
set to a file, the counts (inputs tried, accepted, refused, crashes) are written there as
JSON; ``docs/reliability.md`` reports those of the last long campaign.
"""
from __future__ import annotations

import json
import os
import string
import subprocess
import tempfile
import warnings
from collections import Counter
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from capsmech.errors import CapsmechError
from capsmech.imaging.frames import read_frames
from capsmech.inversion.fitting import fit_tube_rows
from capsmech.io.contours import contour_asymmetry, profile_misfit, read_contour
from capsmech.io.database import load_database
from capsmech.io.measurements import FLOWS, UNITS, read_measurements
from capsmech.io.results import read_results_csv
from capsmech.workflow.paths import capsim_executable

FAST = settings(max_examples=40, deadline=None, database=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
LONG = settings(max_examples=1000, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

#: Outcomes per reader: tried, accepted, refused, crashes (a crash also fails the test).
COUNTS: dict[str, Counter[str]] = {}


@pytest.fixture(scope="module", autouse=True)
def fuzz_report() -> Iterator[None]:
    yield
    report = os.environ.get("CAPSMECH_FUZZ_REPORT")
    if report:
        Path(report).write_text(json.dumps({k: dict(v) for k, v in COUNTS.items()}, indent=2) + "\n")


def outcome(reader: str, attempt: Callable[[], object], refusals: tuple[type[BaseException], ...],
            where: str) -> object | None:
    """Run ``attempt``: its result, or None when it refused with ``refusals`` naming ``where``."""
    counts = COUNTS.setdefault(reader, Counter())
    counts["tried"] += 1
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = attempt()
    except refusals as err:
        assert where in str(err), (where, str(err))
        counts["refused"] += 1
        return None
    except Exception:
        counts["crashes"] += 1
        raise
    counts["accepted"] += 1
    return result


# --- Measurement CSV ------------------------------------------------------------------------

NUMBERS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.floats(min_value=1e-3, max_value=1e3).map(lambda v: f"{v:.4g}"),
    st.sampled_from(["", "0", "-1", "1e300", "1e-320", "nan", "inf", "1_0", "0,5", " 3 ", "x", "1e999", "١٢"]),
)
CELL_TEXT_SAFE = st.text(alphabet=string.ascii_letters + " éµ", max_size=8)
GOOD_NUMBERS = st.floats(min_value=1, max_value=200).map(lambda v: f"{v:.4g}")
#: Plausible values per column (a tube capsule of ~50 um in a 50 um tube; L2 below L1).
PLAUSIBLE = {"L_z": st.floats(100, 160).map(lambda v: f"{v:.4g}"), "L_p": st.floats(0, 40).map(lambda v: f"{v:.4g}"),
             "tube_radius": st.just("50"), "L1": st.floats(40, 60).map(lambda v: f"{v:.4g}"),
             "L2": st.floats(10, 39).map(lambda v: f"{v:.4g}"), "theta": st.floats(0, 89).map(lambda v: f"{v:.4g}"),
             "contour": st.just(""), "note": CELL_TEXT_SAFE}
CELL_TEXT = st.text(alphabet=string.printable + "éµμ\u00a0#\"", max_size=12)


@st.composite
def measurement_files(draw: st.DrawFn) -> bytes:
    flow = draw(st.sampled_from(sorted(FLOWS)))
    columns = FLOWS[flow]
    names = ["id", *draw(st.lists(st.sampled_from(sorted(columns) + ["note", "L_z", "Lz"]), max_size=4))]
    if draw(st.integers(0, 3)) != 3:     # Hypothesis favours small draws: 0 is the plausible branch
        required = [c for c, (_, needed) in columns.items() if needed]
        names = ["id", *required, *[n for n in names[1:] if n not in required or draw(st.integers(0, 9)) == 0]]
    header = []
    for name in names:
        kind = columns.get(name, ("length", False))[0]
        unit = draw(st.sampled_from(sorted(UNITS[kind]))) if draw(st.integers(0, 5)) != 5 else draw(CELL_TEXT)
        header.append(name if name == "id" else f"{name} [{unit}]")
    separator = draw(st.sampled_from([",", ";", "\t"]))
    rows = [separator.join(header)]
    for i in range(draw(st.integers(0, 6))):
        good = draw(st.integers(0, 9)) != 9     # mostly plausible rows, so that the fit is exercised too
        cells = [f"c{i}" if good else draw(st.one_of(st.just(f"c{i}"), CELL_TEXT))]
        cells += [draw(PLAUSIBLE.get(name, GOOD_NUMBERS) if good else st.one_of(NUMBERS, CELL_TEXT))
                  for name in names[1:]]
        cells = cells[:draw(st.integers(0, len(cells) + 1))] if draw(st.integers(0, 9)) == 0 else cells
        rows.append(separator.join(cells))
        if draw(st.integers(0, 7)) == 0:
            rows.append("# " + draw(CELL_TEXT))
    text = draw(st.sampled_from(["\n", "\r\n", "\r"])).join(rows) + "\n"
    encoding = draw(st.sampled_from(["utf-8", "utf-8-sig", "cp1252", "latin-1"]))
    return text.encode(encoding, errors="replace")


def mutated(valid: bytes) -> st.SearchStrategy[bytes]:
    """``valid`` with bytes flipped, inserted or cut (what a failing disk or a careless edit does)."""
    @st.composite
    def damage(draw: st.DrawFn) -> bytes:
        data = bytearray(valid)
        for _ in range(draw(st.integers(1, 4))):
            at = draw(st.integers(0, max(0, len(data) - 1)))
            action = draw(st.sampled_from(["flip", "insert", "cut", "truncate"]))
            if action == "flip" and data:
                data[at] ^= 1 << draw(st.integers(0, 7))
            elif action == "insert":
                data[at:at] = draw(st.binary(min_size=1, max_size=4))
            elif action == "cut":
                del data[at:at + draw(st.integers(1, 8))]
            else:
                del data[at:]
        return bytes(data)
    return damage()


EXAMPLE_CSV = (Path(__file__).resolve().parents[2] / "data" / "examples" / "tube_batch_NH.csv").read_bytes()
CSV_INPUTS = st.one_of(measurement_files(), st.binary(max_size=300), mutated(EXAMPLE_CSV.split(b"s003")[0]))


@pytest.fixture(scope="module")
def tube_dev():
    return load_database("tube-dev")


def check_measurement_file(data: bytes, database) -> None:
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "fuzz.csv"
        path.write_bytes(data)
        capsules = outcome("measurement CSV", lambda: read_measurements(path), (CapsmechError,), str(path))
        if capsules is None:
            return
        assert capsules and len({c.id for c in capsules}) == len(capsules)
        for capsule in capsules:
            assert all(np.isfinite(v) and v >= 0 for v in capsule.values.values()), capsule
        if "L_z" in capsules[0].values:
            # Whatever the reader accepts, the batch fit flags or fits, row by row.
            rows = fit_tube_rows(capsules, database, ["NH"])
            assert [r["id"] for r in rows] == [c.id for c in capsules]


@FAST
@given(CSV_INPUTS)
def test_measurement_reader_refuses_or_reads(tube_dev, data: bytes) -> None:
    check_measurement_file(data, tube_dev)


@pytest.mark.validate
@LONG
@given(CSV_INPUTS)
def test_measurement_reader_campaign(tube_dev, data: bytes) -> None:
    check_measurement_file(data, tube_dev)


# --- Contour files --------------------------------------------------------------------------

COORDINATES = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.floats(-1e3, 1e3),
                        st.sampled_from([0.0, 1e-300, 1e300, -0.0, 5e-324]))


@st.composite
def contour_files(draw: st.DrawFn) -> bytes:
    if draw(st.integers(0, 3)) != 3:
        n = draw(st.integers(8, 60))
        t = np.linspace(0, 2 * np.pi, max(n, 1), endpoint=False)
        scale = draw(st.sampled_from([1.0, 1.0, 1.0, 1e-5, 1e5, 1e-300, 1e-70, 1e70, 1e300, 0.0]))
        aspect = draw(st.sampled_from([1.0, 0.8, 0.5, 0.5, 0.0, 1e-9]))
        points = scale * np.column_stack([10 + 5 * np.cos(t), 3 + 5 * aspect * np.sin(t)])
        if draw(st.integers(0, 5)) == 0:
            points = points[draw(st.permutations(range(len(points))))]
        if draw(st.integers(0, 3)) == 0:      # a bump on one half: an asymmetric capsule
            points[: len(points) // 4, 1] *= 1.1
        lines = [f"{float(x)!r}\t{float(y)!r}" for x, y in points]
    else:
        lines = [draw(st.sampled_from(["{}\t{}", "{},{}", "{} {} 255", "{};{}", "{}"])).format(
            draw(COORDINATES), draw(COORDINATES)) for _ in range(draw(st.integers(0, 30)))]
    if draw(st.booleans()):
        lines.insert(0, draw(st.sampled_from(["X\tY", "# traced", "x y z", "é µ"])))
    return "\n".join(lines).encode(draw(st.sampled_from(["utf-8", "latin-1"])), errors="replace")


CONTOUR_INPUTS = st.one_of(contour_files(), st.binary(max_size=200))
SPHERE = np.column_stack([np.sin(np.linspace(0, np.pi, 33)), -np.cos(np.linspace(0, np.pi, 33))])


def check_contour_file(data: bytes) -> None:
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "contour.txt"
        path.write_bytes(data)
        contour = outcome("contour", lambda: read_contour(path), (CapsmechError,), str(path))
        if contour is None:
            return
        # What the reader accepts can be measured: finite or infinite numbers, no exception.
        asymmetry, limit, axis_y = contour_asymmetry(contour, pixel_size=1.0)
        assert not np.isnan(asymmetry) and np.isfinite(limit) and np.isfinite(axis_y)
        size = float(np.ptp(contour[:, 0]))
        misfit, _ = profile_misfit(contour, SPHERE * size / 2, axis_y)
        assert np.isfinite(misfit)


@FAST
@given(CONTOUR_INPUTS)
def test_contour_reader_refuses_or_reads(data: bytes) -> None:
    check_contour_file(data)


@pytest.mark.validate
@LONG
@given(CONTOUR_INPUTS)
def test_contour_reader_campaign(data: bytes) -> None:
    check_contour_file(data)


# --- Results files (population) -------------------------------------------------------------

@st.composite
def results_files(draw: st.DrawFn) -> bytes:
    names = draw(st.lists(st.sampled_from(["id", "law", "Delta [1]", "G_s [N/m]", "H_over_a [1]", "flag", "reason",
                                           "L_z [um]", "x"]), max_size=8, unique=True))
    good = draw(st.integers(0, 2)) != 2
    if good:
        names = ["id", "law", "Delta [1]", "G_s [N/m]", "H_over_a [1]", "flag", "reason"]
    rows = [",".join(names)]
    for i in range(draw(st.integers(0, 12))):
        law = draw(st.sampled_from(["NH", "GH_nu0.5"]))
        plausible = {"id": f"c{i // 2}", "law": law, "flag": draw(st.sampled_from(["", "", "outside_database",
                                                                                   "asymmetric", "no_velocity"]))}
        rows.append(",".join(plausible.get(name, draw(GOOD_NUMBERS)) if good and name in plausible or good
                             and name != "reason" else draw(st.one_of(NUMBERS, CELL_TEXT, st.just(f"c{i}")))
                             for name in names))
    return "\n".join(rows).encode()


RESULTS_INPUTS = st.one_of(results_files(), st.binary(max_size=200))


def check_results_file(data: bytes) -> None:
    from capsmech import population

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "results.csv"
        path.write_bytes(data)
        rows = outcome("results CSV", lambda: read_results_csv(path), (CapsmechError,), str(path))
        if rows is None:
            return
        try:
            population(rows)     # accepted rows give a verdict, or population's own refusal
        except CapsmechError:
            pass


@FAST
@given(RESULTS_INPUTS)
def test_results_reader_refuses_or_reads(data: bytes) -> None:
    check_results_file(data)


@pytest.mark.validate
@LONG
@given(RESULTS_INPUTS)
def test_results_reader_campaign(data: bytes) -> None:
    check_results_file(data)


# --- Images ---------------------------------------------------------------------------------

def _valid_tiff(pages: int, dtype: str) -> bytes:
    import tifffile

    rng = np.random.default_rng(pages)
    stack = (rng.random((pages, 24, 32)) * (255 if dtype == "uint8" else 4000)).astype(dtype)
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "x.tif"
        tifffile.imwrite(path, stack, imagej=True)
        return path.read_bytes()


def _valid_png() -> bytes:
    import imageio.v3 as iio

    return bytes(iio.imwrite("<bytes>", np.arange(24 * 32, dtype=np.uint8).reshape(24, 32), extension=".png"))


IMAGES = {"tif": [_valid_tiff(1, "uint8"), _valid_tiff(3, "uint16")], "png": [_valid_png()]}
IMAGE_INPUTS = st.one_of(*[st.tuples(st.just(suffix), mutated(image)) for suffix, images in IMAGES.items()
                           for image in images],
                         st.tuples(st.sampled_from(["tif", "png"]), st.binary(max_size=200)))


def check_image(item: tuple[str, bytes]) -> None:
    suffix, data = item
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / f"frames.{suffix}"
        path.write_bytes(data)
        stack = outcome("image", lambda: read_frames([path]), (CapsmechError,), str(path))
        if stack is None:
            return
        shapes = {frame.shape for frame in stack.frames}
        assert len(shapes) == 1 and min(next(iter(shapes))) >= 16


@FAST
@given(IMAGE_INPUTS)
def test_image_reader_refuses_or_reads(item: tuple[str, bytes]) -> None:
    check_image(item)


@pytest.mark.validate
@LONG
@given(IMAGE_INPUTS)
def test_image_reader_campaign(item: tuple[str, bytes]) -> None:
    check_image(item)


# --- The kernel's namelist ------------------------------------------------------------------

NAMELIST_VALUES = {
    "flow": ["'shear'", "'tube'", "'pipe'", "shear", "''", "1"],
    "law": ["'NH'", "'SK'", "'GH'", "'XX'", "'NH   X'"],
    "model": ["'axi'", "'xyz'"],
    "ca": ["0.1", "0.5", "0", "-1", "1e999", "NaN", "Infinity", "0.05 junk", "'x'", "1d-1"],
    "nu_s": ["0.5", "1", "-2", "NaN"],
    "c": ["1", "-1"],
    "lambda": ["1", "0", "1e7"],
    "kb": ["0", "0.01", "2"],
    "a_over_l": ["0.8", "0", "2", "NaN"],
    "level": ["1", "2", "0", "6", "-1", "1.5"],
    "n_meridian": ["8", "16", "4", "2000"],
    "dt": ["0", "0.001", "-1", "NaN"],
    "t_max": ["0.02", "0.05", "-1", "0", "Infinity", "1e300"],
    "threads": ["1", "-1", "1000000"],
    "out": ["'{out}'", "'/nonexistent/x.h5'", "''", "'{folder}'"],
    "bogus": ["1"],
}


@st.composite
def namelists(draw: st.DrawFn) -> str:
    keys = draw(st.lists(st.sampled_from(sorted(NAMELIST_VALUES)), max_size=4))
    pairs = [f"{key}={draw(st.sampled_from(NAMELIST_VALUES[key]))}" for key in keys]
    if not draw(st.booleans()):  # a valid case, then the drawn assignments (a repeat is the namelist's last)
        base = draw(st.sampled_from(["flow='shear', law='NH', ca=0.1, level=1",
                                     "flow='tube', law='GH', nu_s=0.5, ca=0.2, a_over_l=0.8, n_meridian=16"]))
        pairs = [base, "out='{out}'", *pairs]
    body = draw(st.sampled_from([", ", "\n ", " "])).join(pairs)
    text = draw(st.sampled_from(["&capsim\n {}\n/\n", "&capsim {} /", "&other {} /", "{}", "&capsim\n {}\n"]))
    text = text.format(body)
    if draw(st.integers(0, 5)) == 0:
        text += draw(st.text(max_size=20))
    return text


def check_namelist(capsim: Path, text: str) -> None:
    counts = COUNTS.setdefault("kernel namelist", Counter())
    counts["tried"] += 1
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "case.h5"
        nml = Path(folder) / "case.nml"
        nml.write_text(text.replace("{out}", str(out)).replace("{folder}", folder), errors="replace")
        # A valid namelist runs a case: the command line keeps it to a few steps.
        try:
            run = subprocess.run([str(capsim), "--namelist", str(nml), "--quiet", "--threads", "1", "--t-max", "0.05"],
                                 capture_output=True,
                                 text=True, timeout=60, errors="replace")
        except subprocess.TimeoutExpired:
            counts["crashes"] += 1
            raise
        if run.returncode == 2:
            lines = run.stderr.strip().splitlines()
            ok = len(lines) == 1 and lines[0].startswith("capsim: error:")
            counts["refused" if ok else "crashes"] += 1
            assert ok, run.stderr
        else:
            ok = run.returncode in (0, 1) and "signal" not in run.stderr.lower()
            counts["accepted" if ok else "crashes"] += 1
            assert ok, (run.returncode, run.stderr)


@pytest.fixture(scope="module")
def capsim() -> Path:
    try:
        path = capsim_executable()
    except FileNotFoundError as err:
        pytest.skip(f"no kernel: {err}")
    return path


@FAST
@given(namelists())
def test_kernel_namelist_refuses_or_runs(capsim: Path, text: str) -> None:
    check_namelist(capsim, text)


@pytest.mark.validate
@settings(LONG, max_examples=400)
@given(namelists())
def test_kernel_namelist_campaign(capsim: Path, text: str) -> None:
    check_namelist(capsim, text)
