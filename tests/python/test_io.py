"""Tests of capsmech.io.case (case-file reader) and the capsmech CLI on synthetic case files.

No kernel is needed: every case file is written here with h5py.
"""

from __future__ import annotations

import math
import os
import stat
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest

import capsmech
from capsmech.cli.case import out_path_from_args
from capsmech.cli.main import main
from capsmech.io.case import CaseFileError, CaseResult, NotSteadyError, read_case
from capsmech.workflow.paths import capsim_executable, repo_root

# ---------------------------------------------------------------------------
# Synthetic case files
# ---------------------------------------------------------------------------


def icosahedron() -> tuple[np.ndarray, np.ndarray]:
    """Return the nodes (12, 3) on the unit sphere and 0-based triangles (20, 3)."""
    phi = (1.0 + 5.0**0.5) / 2.0
    nodes = np.array(
        [
            [-1, phi, 0], [1, phi, 0], [-1, -phi, 0], [1, -phi, 0],
            [0, -1, phi], [0, 1, phi], [0, -1, -phi], [0, 1, -phi],
            [phi, 0, -1], [phi, 0, 1], [-phi, 0, -1], [-phi, 0, 1],
        ],
        dtype=float,
    )
    nodes /= np.linalg.norm(nodes, axis=1, keepdims=True)
    triangles = np.array(
        [
            [0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11],
            [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6], [7, 1, 8],
            [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9],
            [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1],
        ],
        dtype=np.int32,
    )
    return nodes, triangles


BASE_ATTRS: dict[str, Any] = {
    "schema_version": 1,
    "code_version": "capsim 0.1.0-test",
    "flow": "shear",
    "law": "NH",
    "nu_s": 0.5,
    "C": 1.0,
    "Ca_s": 0.05,
    "mesh_level": 0,
    "dt": 1.0e-3,
    "status": "steady",
    "message": "converged: |dD12/dt| < 1e-4",
    "wall_time_s": 1.25,
    "threads": 2,
}

STEADY_D12 = 0.1234


def write_case(
    path: Path,
    *,
    attrs: dict[str, Any] | None = None,
    drop_attrs: tuple[str, ...] = (),
    bytes_strings: bool = False,
    steady: bool = True,
    no_units: str | None = None,
    transpose_nodes: bool = False,
) -> Path:
    """Write a small valid case file (icosahedral mesh, ellipse profile), with optional defects.

    Parameters
    ----------
    path : Path
        File to write.
    attrs : dict, optional
        Root attributes overriding :data:`BASE_ATTRS`.
    drop_attrs : tuple of str
        Root attributes to leave out.
    bytes_strings : bool
        Write string attributes as fixed-length byte strings padded with
        blanks (as a Fortran writer may) instead of variable-length str.
    steady : bool
        Whether to write the ``/steady`` group.
    no_units : str, optional
        Path of a dataset to write without its ``units`` attribute.
    transpose_nodes : bool
        Write ``/mesh/nodes`` as (3, n), as a careless column-major writer would.
    """
    all_attrs = {**BASE_ATTRS, **(attrs or {})}
    n_t = 50
    t = np.linspace(0.0, n_t * 1.0e-3 * 100, n_t)
    d12 = STEADY_D12 * (1.0 - np.exp(-t))
    history = {
        "t": (t, "1/G"),
        "D12": (d12, "-"),
        "L1": (1.0 + d12, "a"),
        "L2": (1.0 - d12, "a"),
        "L3": (np.ones(n_t), "a"),
        "theta": (np.full(n_t, math.pi / 4), "rad"),
        "area": (np.full(n_t, 4 * math.pi), "a^2"),
        "volume": (np.full(n_t, 4 * math.pi / 3), "a^3"),
    }
    steady_values = {
        "D12": (STEADY_D12, "-"), "L1": (1 + STEADY_D12, "a"), "L2": (1 - STEADY_D12, "a"),
        "L3": (1.0, "a"), "theta": (0.6, "rad"), "area": (4 * math.pi, "a^2"),
        "volume": (4 * math.pi / 3, "a^3"), "t": (float(t[-1]), "1/G"),
    }
    nodes, triangles = icosahedron()
    angle = np.linspace(0.0, 2 * math.pi, 64, endpoint=False)

    with h5py.File(path, "w") as f:
        for name, value in all_attrs.items():
            if name in drop_attrs:
                continue
            if isinstance(value, str) and bytes_strings:
                value = np.bytes_(value.ljust(32).encode())
            f.attrs[name] = value

        def put(dataset_path: str, data: Any, units: str) -> h5py.Dataset:
            ds = f.create_dataset(dataset_path, data=data)
            if dataset_path != no_units:
                ds.attrs["units"] = np.bytes_(units.encode()) if bytes_strings else units
            return ds

        for name, (data, units) in history.items():
            put(f"history/{name}", data, units)
        if steady:
            for name, (value, units) in steady_values.items():
                put(f"steady/{name}", value, units)
        put("mesh/reference_nodes", nodes, "a")
        put("mesh/nodes", (nodes * [1.1, 0.9, 1.0]).T if transpose_nodes else nodes * [1.1, 0.9, 1.0], "a")
        put("mesh/triangles", triangles, "-").attrs["index_base"] = 0
        put("profile/y", 1.1 * np.cos(angle), "a")
        put("profile/z", 0.9 * np.sin(angle), "a")
    return path


@pytest.fixture
def make_case(tmp_path: Path) -> Callable[..., Path]:
    """Factory writing a case file into tmp_path: ``make_case(name='case.h5', **write_case_kwargs)``."""

    def factory(name: str = "case.h5", **kwargs: Any) -> Path:
        return write_case(tmp_path / name, **kwargs)

    return factory


@pytest.fixture
def case_file(make_case: Callable[..., Path]) -> Path:
    """A valid, steady shear case file."""
    return make_case()


# ---------------------------------------------------------------------------
# read_case: valid files
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("bytes_strings", [False, True], ids=["str", "fixed-bytes"])
def test_valid_file_round_trips(make_case: Callable[..., Path], bytes_strings: bool) -> None:
    path = make_case(bytes_strings=bytes_strings)
    case = read_case(path)

    assert isinstance(case, CaseResult)
    assert capsmech.read_case is read_case and capsmech.CaseResult is CaseResult
    for name, expected in BASE_ATTRS.items():
        assert getattr(case, name) == expected, name
    assert math.isnan(case.a_over_l)  # absent for shear flow
    assert case.is_steady
    assert case.steady_value("D12") == pytest.approx(STEADY_D12)
    assert case.steady["theta"] == pytest.approx(0.6)
    assert case.unit("steady/D12") == "-" and case.unit("history/t") == "1/G"
    assert set(case.history) == {"t", "D12", "L1", "L2", "L3", "theta", "area", "volume"}
    assert all(a.shape == (50,) for a in case.history.values())
    assert case.mesh["nodes"].shape == (12, 3) and case.mesh["triangles"].shape == (20, 3)
    assert case.mesh["triangles"].min() == 0
    assert case.profile["y"].shape == case.profile["z"].shape == (64,)
    assert str(path) in repr(case)


def test_case_result_is_immutable(case_file: Path) -> None:
    case = read_case(case_file)
    with pytest.raises(AttributeError):
        case.status = "failed"  # type: ignore[misc]
    with pytest.raises(ValueError):
        case.history["D12"][0] = 1.0


def test_tube_case_reads_a_over_l(make_case: Callable[..., Path]) -> None:
    case = read_case(make_case(attrs={"flow": "tube", "a_over_l": 0.8}))
    assert case.flow == "tube" and case.a_over_l == pytest.approx(0.8)


# ---------------------------------------------------------------------------
# read_case: invalid files
# ---------------------------------------------------------------------------


def test_truncated_file_names_the_file(case_file: Path) -> None:
    size = case_file.stat().st_size
    with open(case_file, "r+b") as fh:
        fh.truncate(size // 2)
    with pytest.raises(CaseFileError, match=case_file.name):
        read_case(case_file)


def test_not_hdf5_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "notes.h5"
    path.write_text("this is not HDF5\n")
    with pytest.raises(CaseFileError, match=r"notes\.h5.*not an HDF5 file"):
        read_case(path)


def test_missing_file_raises_file_not_found(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="nowhere.h5"):
        read_case(tmp_path / "nowhere.h5")


@pytest.mark.parametrize("attr", ["Ca_s", "status", "schema_version", "threads"])
def test_missing_attribute_is_named(make_case: Callable[..., Path], attr: str) -> None:
    with pytest.raises(CaseFileError, match=f"missing required root attribute '{attr}'"):
        read_case(make_case(drop_attrs=(attr,)))


def test_tube_without_a_over_l_is_named(make_case: Callable[..., Path]) -> None:
    with pytest.raises(CaseFileError, match="a_over_l"):
        read_case(make_case(attrs={"flow": "tube"}))


def test_wrong_schema_version_is_named(make_case: Callable[..., Path]) -> None:
    with pytest.raises(CaseFileError, match=r"'schema_version' is 2"):
        read_case(make_case(attrs={"schema_version": 2}))


def test_unknown_status_is_named(make_case: Callable[..., Path]) -> None:
    with pytest.raises(CaseFileError, match=r"'status' is 'exploded'"):
        read_case(make_case(attrs={"status": "exploded"}))


@pytest.mark.parametrize("dataset", ["history/D12", "steady/theta", "mesh/triangles", "profile/z"])
def test_dataset_without_units_is_named(make_case: Callable[..., Path], dataset: str) -> None:
    with pytest.raises(CaseFileError, match=f"'/{dataset}' has no 'units' attribute"):
        read_case(make_case(no_units=dataset))


def test_transposed_mesh_is_diagnosed(make_case: Callable[..., Path]) -> None:
    with pytest.raises(CaseFileError, match=r"/mesh/nodes.*transposed"):
        read_case(make_case(transpose_nodes=True))


def test_steady_status_without_steady_group_is_an_error(make_case: Callable[..., Path]) -> None:
    with pytest.raises(CaseFileError, match="/steady"):
        read_case(make_case(steady=False))


# ---------------------------------------------------------------------------
# Non-steady cases
# ---------------------------------------------------------------------------

ELONGATION = {"status": "continuous_elongation", "message": "L1 grows without bound past t = 40"}


@pytest.mark.parametrize("steady_group", [False, True], ids=["no-steady-group", "stale-steady-group"])
def test_steady_value_of_non_steady_case_raises(
    make_case: Callable[..., Path], steady_group: bool
) -> None:
    case = read_case(make_case(attrs=ELONGATION, steady=steady_group))
    assert not case.is_steady
    assert case.steady == {}  # never a number from a non-steady case
    with pytest.raises(NotSteadyError, match="continuous_elongation") as err:
        case.steady_value("D12")
    assert ELONGATION["message"] in str(err.value)


def test_unknown_steady_value_is_key_error(case_file: Path) -> None:
    with pytest.raises(KeyError, match="Taylor"):
        read_case(case_file).steady_value("Taylor")


# ---------------------------------------------------------------------------
# CLI: show
# ---------------------------------------------------------------------------


def test_show_valid_file(case_file: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["show", str(case_file)]) == 0
    out = capsys.readouterr().out
    for text in ("shear", "NH", "steady", BASE_ATTRS["message"], "D12", "[rad]", "1.25 s"):
        assert text in out, text


def test_show_non_steady_file(make_case: Callable[..., Path], capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["show", str(make_case(attrs=ELONGATION, steady=False))]) == 0
    out = capsys.readouterr().out
    assert "continuous_elongation" in out and ELONGATION["message"] in out


def test_show_missing_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / "absent.h5"
    assert main(["show", str(missing)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("capsmech: error: ") and "absent.h5" in err


def test_show_corrupt_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.h5"
    bad.write_bytes(b"\x00" * 100)
    assert main(["show", str(bad)]) == 2
    assert "capsmech: error: " in capsys.readouterr().err


@pytest.mark.parametrize("attrs", [{}, ELONGATION], ids=["steady", "non-steady"])
def test_show_plot_writes_png(
    make_case: Callable[..., Path], tmp_path: Path, attrs: dict[str, Any]
) -> None:
    png = tmp_path / "plots" / "case.png"
    assert main(["show", str(make_case(attrs=attrs)), "--plot", str(png)]) == 0
    data = png.read_bytes()
    assert len(data) > 1000 and data.startswith(b"\x89PNG")


def test_show_rejects_unknown_option(case_file: Path) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["show", str(case_file), "--bogus"])
    assert exit_info.value.code == 2


# ---------------------------------------------------------------------------
# CLI: simulate (with a stand-in kernel) and paths
# ---------------------------------------------------------------------------


def fake_kernel(tmp_path: Path, source: Path, exit_code: int = 0) -> Path:
    """Write an executable stand-in for capsim that echoes its arguments and copies ``source`` to --out."""
    script = tmp_path / "fake_capsim"
    script.write_text(
        f"#!{sys.executable}\n"
        "import shutil, sys\n"
        "args = sys.argv[1:]\n"
        "print('fake capsim:', ' '.join(args), flush=True)\n"
        "out = args[args.index('--out') + 1] if '--out' in args else None\n"
        f"if out:\n    shutil.copyfile({str(source)!r}, out)\n"
        f"sys.exit({exit_code})\n"
    )
    script.chmod(script.stat().st_mode | stat.S_IXUSR)
    return script


def test_simulate_passes_arguments_and_shows_case(
    case_file: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv("CAPSIM", str(fake_kernel(tmp_path, case_file)))
    out = tmp_path / "runs" / "new.h5"  # parent directory does not exist yet
    args = ["--flow", "shear", "--law", "NH", "--ca", "0.05", "--level", "3", "--out", str(out)]
    assert main(["simulate", *args]) == 0
    stdout = capsys.readouterr().out
    assert "fake capsim: " + " ".join(args) in stdout
    assert "status      steady" in stdout and out.is_file()


def test_simulate_returns_kernel_exit_code(
    case_file: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("CAPSIM", str(fake_kernel(tmp_path, case_file, exit_code=3)))
    assert main(["simulate", "--help"]) == 3


def test_simulate_without_kernel(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv("CAPSIM", str(tmp_path / "no_such_capsim"))
    assert main(["simulate", "--flow", "shear"]) == 2
    assert "make build" in capsys.readouterr().err


def test_capsim_executable_default_location(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("CAPSIM", raising=False)
    root = repo_root()
    assert (root / "Makefile").is_file() and (root / "kernel").is_dir()
    expected = root / "bin" / "capsim"
    if expected.is_file() and os.access(expected, os.X_OK):
        assert capsim_executable() == expected
    else:
        with pytest.raises(FileNotFoundError, match="make build"):
            capsim_executable()


def test_out_path_from_args() -> None:
    assert out_path_from_args(["--out", "a.h5"]) == Path("a.h5")
    assert out_path_from_args(["--out=b/c.h5", "--ca", "1"]) == Path("b/c.h5")
    assert out_path_from_args(["--ca", "1"]) is None


def test_show_summarises_and_plots_an_axisymmetric_tube_case(tmp_path: Path, capsys) -> None:
    # The tube case file carries a meridian (n, 2) instead of a triangle mesh, and an (r, z) profile.
    path = tmp_path / "tube.h5"
    theta = np.linspace(0, np.pi, 17)
    rz = np.c_[0.8 * np.sin(theta), 0.8 * np.cos(theta)]
    with h5py.File(path, "w") as f:
        for key, value in dict(schema_version=np.int32(1), code_version="0.1.0", flow="tube", law="NH",
                               nu_s=0.5, C=1.0, Ca_s=0.05, a_over_l=0.8, mesh_level=np.int32(3), dt=1e-3,
                               status="steady", message="ok", wall_time_s=1.0, threads=np.int32(1)).items():
            f.attrs[key] = value
        for group, data in {"history": {"t": np.array([0.0, 1.0]), "L_z": np.array([1.6, 1.7])},
                            "steady": {"L_z": np.float64(1.7)},
                            "mesh": {"reference_meridian": rz, "meridian": rz},
                            "profile": {"r": rz[:, 0], "z": rz[:, 1]}}.items():
            for name, values in data.items():
                f.create_dataset(f"{group}/{name}", data=values).attrs["units"] = "l"
    assert main(["show", str(path), "--plot", str(tmp_path / "tube.png")]) == 0
    out = capsys.readouterr().out
    assert "meridian of 17 nodes" in out and "tube" in out
    assert (tmp_path / "tube.png").stat().st_size > 0
