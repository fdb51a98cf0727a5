"""Pins the HDF5 layout written by the kernel's hdf5_writer module, as seen from h5py.

The Fortran check program ``bin/hdf5_writer_check`` writes a small case-like file; this test
reads it back so that the conventions the analysis code relies on (Fortran ``x(3,n)`` reads as
``(n,3)``, scalar datasets, ``units`` attributes, gzip on large datasets, checksums on every
dataset, errors returned rather than aborting) cannot drift silently.
"""

import subprocess
from pathlib import Path

import h5py
import numpy as np
import pytest

REPO_ROOT = Path(__file__).resolve().parents[2]
CHECK_EXE = REPO_ROOT / "bin" / "hdf5_writer_check"


def text(value):
    """Fixed-length HDF5 strings come back as bytes (or str, depending on h5py); compare text."""
    if isinstance(value, np.ndarray) and value.shape == ():
        value = value[()]
    if isinstance(value, (bytes, np.bytes_)):
        return value.decode("ascii")
    return str(value)


@pytest.fixture(scope="session")
def check_exe():
    if not CHECK_EXE.is_file():
        pytest.fail(f"{CHECK_EXE} is missing: run `make build` in {REPO_ROOT} first")
    return CHECK_EXE


@pytest.fixture(scope="session")
def written(check_exe, tmp_path_factory):
    out = tmp_path_factory.mktemp("hdf5_writer") / "check.h5"
    proc = subprocess.run(
        [str(check_exe), str(out)], capture_output=True, text=True, timeout=60, check=False
    )
    assert proc.returncode == 0, f"hdf5_writer_check failed:\n{proc.stdout}\n{proc.stderr}"
    return out, proc


@pytest.fixture
def h5(written):
    with h5py.File(written[0], "r") as f:
        yield f


def test_program_reports_ok_and_no_hdf5_noise(written):
    _, proc = written
    lines = proc.stdout.split()
    assert lines[-1] == "ok"
    # The library silences HDF5's own error-stack printing; the expected failure must be quiet.
    assert proc.stderr == ""


def test_error_path_is_returned_not_aborted(written):
    _, proc = written
    assert "error_path_ok 1" in proc.stdout.splitlines()


def test_root_attributes(h5):
    attrs = h5["/"].attrs
    assert attrs["schema_version"] == 1
    assert np.issubdtype(np.asarray(attrs["schema_version"]).dtype, np.integer)
    assert text(attrs["flow"]) == "shear"
    assert attrs["Ca_s"] == 0.05
    assert np.asarray(attrs["Ca_s"]).dtype == np.float64


def test_string_attribute_has_no_padding(h5):
    raw = h5["/"].attrs["flow"]
    assert len(text(raw)) == len("shear")
    assert "\x00" not in text(raw)
    assert h5["/history/t"].attrs.get_id("units").get_type().get_size() == len("1/gamma_dot")


def test_nodes_fortran_3n_reads_as_n3(h5):
    nodes = h5["/mesh/nodes"]
    assert nodes.shape == (5, 3)
    assert nodes.dtype == np.float64
    data = nodes[()]
    for j in range(1, 6):
        for i in range(1, 4):
            assert data[j - 1, i - 1] == 10 * j + i
    assert text(nodes.attrs["units"]) == "a"
    # Small datasets are not compressed (the filter's overhead would outweigh any saving), but
    # chunked, as their checksum needs.
    assert nodes.compression is None
    assert nodes.fletcher32


def test_triangles(h5):
    tri = h5["/mesh/triangles"]
    assert tri.shape == (2, 3)
    assert np.issubdtype(tri.dtype, np.integer)
    np.testing.assert_array_equal(tri[()], [[0, 1, 2], [2, 3, 4]])
    assert text(tri.attrs["units"]) == "1"


def test_scalar_dataset(h5):
    d12 = h5["/steady/D12"]
    assert d12.shape == ()
    value = d12[()]
    assert isinstance(value, (float, np.floating))
    assert value == 0.25
    assert text(d12.attrs["units"]) == "1"


def test_history_t_is_gzip_compressed(h5):
    t = h5["/history/t"]
    assert t.shape == (100,)
    assert t.compression == "gzip"
    assert t.compression_opts == 4
    assert t.chunks is not None
    np.testing.assert_allclose(t[()], 0.1 * np.arange(1, 101), rtol=0, atol=1e-15)
    assert text(t.attrs["units"]) == "1/gamma_dot"


def test_failed_write_leaves_no_object(h5):
    assert "nosuch" not in h5


def test_every_dataset_carries_a_checksum(h5):
    # Arrays: Fletcher-32 per chunk. Scalars (rank 0 cannot be chunked): compact, inside their
    # object header, which the file format of HDF5 1.8 on checksums.
    found = []
    h5.visititems(lambda name, obj: found.append(obj) if isinstance(obj, h5py.Dataset) else None)
    assert len(found) == 4
    for ds in found:
        if ds.shape == ():
            assert ds.id.get_create_plist().get_layout() == h5py.h5d.COMPACT, ds.name
        else:
            assert ds.fletcher32, ds.name
    assert h5.id.get_access_plist().get_libver_bounds()[0] >= h5py.h5f.LIBVER_V18


def stored_ranges(path: Path) -> dict[str, tuple[int, int]]:
    """Byte range (offset, size) in the file of each dataset's stored data: the first chunk of
    a chunked dataset; for a compact scalar, the one place its value's bytes occur outside
    every chunk (the value may also be a history entry), if there is one place only (a 0.0
    is everywhere: such scalars are left out)."""
    ranges, scalars = {}, {}
    with h5py.File(path, "r") as f:
        def visit(name, obj):
            if not isinstance(obj, h5py.Dataset):
                return
            if obj.chunks is not None:
                info = obj.id.get_chunk_info(0)
                ranges[name] = (info.byte_offset, info.size)
            else:
                scalars[name] = obj[()].tobytes()
        f.visititems(visit)
    data = path.read_bytes()
    for name, pattern in scalars.items():
        places, at = [], data.find(pattern)
        while at >= 0:
            if not any(o <= at < o + n for o, n in ranges.values()):
                places.append(at)
            at = data.find(pattern, at + 1)
        if len(places) == 1:
            ranges[name] = (places[0], len(pattern))
    return ranges


def f_shape(path: Path, name: str) -> tuple:
    with h5py.File(path, "r") as f:
        return f[name].shape


def test_a_flipped_byte_in_any_dataset_fails_its_read(capsim, tmp_path):
    # A case file with arrays small and large (gzip) and scalars (/steady).
    case = tmp_path / "case.h5"
    subprocess.run([str(capsim), "--flow", "tube", "--law", "NH", "--a-over-l", "0.6", "--ca", "0.003",
                    "--n-meridian", "24", "--integrator", "newton", "--threads", "1", "--quiet", "--out", str(case)],
                   check=True, timeout=300)
    with h5py.File(case, "r") as f:      # whole, it reads
        names = []
        f.visititems(lambda name, obj: names.append(name) if isinstance(obj, h5py.Dataset) else None)
        for name in names:
            f[name][()]
    ranges = stored_ranges(case)
    arrays = [name for name in names if f_shape(case, name) != ()]
    assert set(arrays) <= set(ranges)
    assert len(set(ranges) - set(arrays)) >= 3       # scalars (/steady) too
    for name, (offset, size) in ranges.items():
        damaged = tmp_path / "damaged.h5"
        data = bytearray(case.read_bytes())
        data[offset + size // 2] ^= 0x10
        damaged.write_bytes(bytes(data))
        with h5py.File(damaged, "r") as f, pytest.raises((OSError, KeyError)):
            f[name][()]
