"""Photon time tags (jaxsr.sensor.timetags): readers for .mat cell arrays and .npz tables, histogramming in JAX against
NumPy's `histogram`, and every bad input refused with a message."""

import numpy as np
import pytest
import scipy.io

from jaxsr.config import METRES_PER_SECOND, Gate
from jaxsr.sensor.timetags import gate_of_tags, histogram_time_tags, read_time_tags, time_tags_from_cells

PS = 1e-12
GATE = Gate.from_time(12, 100 * PS, 5000 * PS)  # 12 bins of 100 ps from 5000 ps


def random_cells(rng, shape=(3, 4)):
    """Per-pixel arrival times in ps inside GATE (one pixel empty), away from bin edges by >= 5 ps."""
    cells = np.empty(shape, dtype=object)
    for index in np.ndindex(shape):
        n = 0 if index == (1, 2) else rng.integers(1, 30)
        cells[index] = (5000 + 100 * rng.integers(0, 12, n) + rng.uniform(5, 95, n)).reshape(-1, 1)
    return cells


def numpy_reference(cells):
    edges = 5000 + 100 * np.arange(13)
    return np.stack([np.histogram(np.ravel(c), edges)[0] for c in cells.ravel()]).reshape(*cells.shape, 12)


def test_histogram_equals_numpy_histogram_from_a_mat_file(tmp_path):
    cells = random_cells(np.random.default_rng(0))
    scipy.io.savemat(tmp_path / "tags.mat", {"photon_times": cells, "gate_ps": np.array([[5000, 6200]])})
    tags = read_time_tags(tmp_path / "tags.mat", time_unit_s=PS)
    assert tags.shape == (3, 4) and tags.frames == 1
    counts = histogram_time_tags(tags, GATE)
    assert counts.shape == (1, 3, 4, 12)
    np.testing.assert_array_equal(counts[0], numpy_reference(cells))
    assert counts[0, 1, 2].sum() == 0  # the empty pixel: an empty histogram (no return), not an error


def test_table_and_cells_agree_and_frames_are_kept(tmp_path):
    rng = np.random.default_rng(1)
    cells = np.stack([random_cells(rng), random_cells(rng)])  # (T=2, 3, 4)
    tags = time_tags_from_cells(cells, time_unit_s=PS)
    np.savez(tmp_path / "t.npz", pixel=tags.pixel, time=tags.time, frame=tags.frame, shape=np.array([3, 4]),
             time_unit_s=PS)
    from_table = histogram_time_tags(read_time_tags(tmp_path / "t.npz"), GATE)
    np.testing.assert_array_equal(from_table, histogram_time_tags(tags, GATE))
    np.testing.assert_array_equal(from_table[1], numpy_reference(cells[1]))


def test_nested_lists_and_gate_of_tags():
    tags = time_tags_from_cells([[[10.0, 20.0], []], [[15.0], [30.0, 11.0]]], time_unit_s=1e-9)
    gate = gate_of_tags(tags, bins=4)
    assert gate.start == pytest.approx(10e-9 * METRES_PER_SECOND)
    counts = histogram_time_tags(tags, gate)
    assert counts.sum() == 5 and counts[0, 1, 1, -1] == 1  # the last photon falls inside


@pytest.mark.parametrize("make,match", [
    (lambda p: histogram_time_tags(time_tags_from_cells([[[1.0, 9999.0]]], time_unit_s=PS), GATE),
     "2 of 2 photons arrive outside the gate"),
    (lambda p: time_tags_from_cells([[[1.0], [2.0]], [[3.0]]]), "ragged"),
    (lambda p: time_tags_from_cells(np.array([[np.array(["a"])]], dtype=object)), "expected a vector"),
    (lambda p: time_tags_from_cells([[[1.0, np.nan]]]), "non-finite"),
    (lambda p: histogram_time_tags(time_tags_from_cells([[[1.0]]]), GATE), "time unit of the tags is unknown"),
    (lambda p: (p / "v73.mat").write_bytes(b"MATLAB 7.3 MAT-file, Platform: GLNXA64".ljust(116) + b"\0" * 8
                                           + b"\x00\x02IM" + b"\0" * 400) and read_time_tags(p / "v73.mat"),
     "v7.3"),
    (lambda p: scipy.io.savemat(p / "none.mat", {"x": np.zeros(3)}) or read_time_tags(p / "none.mat"),
     "expected one cell array"),
    (lambda p: (p / "t.csv").write_text("1,2") and read_time_tags(p / "t.csv"), "not .csv"),
    (lambda p: np.savez(p / "t.npz", pixel=np.array([0, 7]), time=np.ones(2), shape=np.array([2, 2]))
     or read_time_tags(p / "t.npz"), "pixel indices"),
])
def test_bad_input_is_a_clear_error(tmp_path, make, match):
    with pytest.raises(ValueError, match=match):
        make(tmp_path)


def test_outside_photons_can_be_dropped():
    tags = time_tags_from_cells([[[5050.0, 9999.0, 10.0]]], time_unit_s=PS)
    assert histogram_time_tags(tags, GATE, outside="drop").sum() == 1
