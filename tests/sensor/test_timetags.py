"""Photon time tags (jaxsr.sensor.timetags): readers for .mat cell arrays and .npz tables, histogramming in JAX against
NumPy's `histogram`, and every bad input refused with a message."""

import re

import numpy as np
import pytest
import scipy.io

from jaxsr.config import METRES_PER_SECOND, Gate
from jaxsr.sensor.timetags import (MAX_AUTO_GATE_M, TimeTags, gate_of_tags, histogram_time_tags, read_time_tags,
                                    time_tag_warnings, time_tags_from_cells)

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


# --- what a recording of time tags can hold ---------------------------------------------------


@pytest.mark.parametrize("unit", [1e-12, 8e-12, 1e-9, 1.0])
def test_the_default_gate_holds_the_first_and_last_photon(unit):
    """gate_of_tags spans the photons: each of them falls inside, whatever the rounding of the conversion to
    metres and back (the last, or the first, photon was refused as outside in 13 of 300 random recordings)."""
    rng = np.random.default_rng(1)
    for bins in (16, 7, 100_000):
        for _ in range(40):
            times = rng.uniform(0, min(1e7, 0.99 * MAX_AUTO_GATE_M / (METRES_PER_SECOND * unit)), 5)  # a gate
            tags = time_tags_from_cells([[times, np.round(times)]], time_unit_s=unit)
            counts = histogram_time_tags(tags, gate_of_tags(tags, bins=bins))
            assert counts.sum() == 10


@pytest.mark.parametrize("first", [0.0, 1e-3, 4.0])
def test_the_default_gate_never_starts_before_time_0(first):
    """A photon at t = 0 gave a gate from -7.5e-8 m (half a millionth of the span before it), where --gate-start
    below 0 is refused: the start is held at 0, and the first photon still falls inside."""
    tags = time_tags_from_cells([[[first, 5050.0], [first, 6000.0, 10_000.0]]], time_unit_s=PS)
    for bins in (16, 100_000):
        gate = gate_of_tags(tags, bins=bins)
        assert float(gate.start) >= 0.0
        if first < 1.0:  # within the margin of 0: the gate starts at 0 exactly
            assert float(gate.start) == 0.0
        counts = histogram_time_tags(tags, gate)
        assert counts.sum() == 5 and counts[..., 0].sum() == 2  # both first photons, in the first bin


def test_negative_arrival_times_are_refused_by_the_default_gate_and_dropped_from_a_given_one():
    tags = time_tags_from_cells([[[-50.0, 5050.0, 5150.0], [-1.0]]], time_unit_s=PS)
    with pytest.raises(ValueError, match=r"2 of 4 photons arrive at negative times \(from -50, in the tags' unit\); "
                                         r"expected times >= 0 from the laser pulse"):
        gate_of_tags(tags)
    with pytest.raises(ValueError, match="2 of 4 photons arrive outside the gate"):
        histogram_time_tags(tags, GATE)
    assert histogram_time_tags(tags, GATE, outside="drop").sum() == 2
    assert time_tag_warnings(tags, GATE, outside="drop") == [
        "cells: 2 of 4 photons outside the gate dropped (--drop-outside)"]


@pytest.mark.parametrize("unit,got", [
    (np.array([1e-12, 1e-12]), "an array of shape (2,)"), (-1e-12, "-1e-12"), (np.nan, "nan"),
    (np.array("1ps"), "'1ps'"), (0, "0"),
])
def test_a_time_unit_that_is_not_one_number_above_0_says_what_was_expected(tmp_path, unit, got):
    """In the file (a vector was a TypeError, a string, negative or NaN "the time unit is unknown") and as the
    argument alike."""
    np.savez(tmp_path / "t.npz", pixel=np.arange(4), time=np.full(4, 5050.0), shape=np.array([2, 2]),
             time_unit_s=unit)
    want = f"expected one number of seconds per time unit, > 0 (such as 1e-12 for picoseconds; --time-unit 1ps on " \
           f"the command line), got {got}"
    with pytest.raises(ValueError, match=re.escape(f"t.npz: 'time_unit_s': {want}")):
        read_time_tags(tmp_path / "t.npz")
    with pytest.raises(ValueError, match=re.escape(f"time_unit_s: {want}")):
        read_time_tags(tmp_path / "t.npz", time_unit_s=unit)
    assert read_time_tags(tmp_path / "t.npz", time_unit_s=PS).time_unit_s == PS  # the argument overrides the file


def test_a_frame_index_of_ten_million_is_refused_with_the_memory_it_would_take(tmp_path):
    np.savez(tmp_path / "t.npz", pixel=np.arange(4), time=np.full(4, 5050.0), frame=np.array([0, 0, 0, 10**7]),
             shape=np.array([8, 8]), time_unit_s=PS)
    tags = read_time_tags(tmp_path / "t.npz")
    with pytest.raises(ValueError, match=r"histogramming 10000001 frames \(frame indices up to 10000000\) of 8 x 8 "
                                         r"pixels x 12 bins needs about 61.4 GB of memory, more than the 1.0 GB "
                                         r"allowed by --max-memory .*check the frame indices"):
        histogram_time_tags(tags, GATE, max_memory="1GB")
    with pytest.raises(ValueError, match=r"makes 7,680,000,768 counts .* more than the 2,147,483,647"):
        histogram_time_tags(tags, GATE, max_memory="1TB")  # within memory, beyond JAX's int32 indices


def test_many_bins_are_refused_before_they_are_allocated():
    tags = TimeTags(np.arange(2048), np.zeros(2048, np.int64), np.full(2048, 5050.0), (32, 64), 1, PS)
    with pytest.raises(ValueError, match=r"of 32 x 64 pixels x 100000 bins needs about 1.6 GB of memory, more than "
                                         r"the 500 MB allowed .*give fewer --bins"):
        histogram_time_tags(tags, Gate.from_time(100_000, 0.012 * PS, 5000 * PS), max_memory="500MB")


def test_a_time_unit_1000x_off_names_the_likely_one():
    """Times in ps read as ns fall outside the gate (refused, or dropped with a warning); read as fs they fall
    inside a sliver of it: either way the message names the unit that fits."""
    times = np.random.default_rng(2).uniform(5005, 6195, 200)
    as_ns = time_tags_from_cells([[times]], time_unit_s=1e-9)
    with pytest.raises(ValueError, match=r"200 of 200 photons arrive outside the gate .*is the time unit right\? "
                                         r"with --time-unit 1ps \(not 1ns\) 100% of them would fall inside, over 9\d% "
                                         r"of the gate"):
        histogram_time_tags(as_ns, GATE)
    wide = Gate.from_time(16, 1e-9, 0.0)  # 0 .. 16 ns
    as_fs = time_tags_from_cells([[times]], time_unit_s=1e-15)
    counts = histogram_time_tags(as_fs, wide)
    assert counts[0, 0, 0, 0] == 200  # every photon in the first bin
    [note] = time_tag_warnings(as_fs, wide)
    assert re.fullmatch(r"cells: the photons fall inside 0.0\d% of the gate; is the time unit right\? with "
                        r"--time-unit 1ps \(not 1fs\) 100% of them would fall inside, over 7% of the gate", note), note
    assert time_tag_warnings(time_tags_from_cells([[times]], time_unit_s=PS), GATE) == []


def test_one_stray_photon_does_not_stretch_the_gate_to_light_years():
    """One photon at 1e300 ps among photons at 10-30 ns: the automatic gate was 1e296 m wide (warned, exit 0);
    now refused with a count and what to give."""
    tags = time_tags_from_cells([[[10.0, 20.0], [1e300]], [[15.0], [30.0, 11.0]]], time_unit_s=1e-12)
    with pytest.raises(ValueError, match=r"the photons span 1.5e\+296 m of range .* 1 of 6 photons lie beyond"):
        gate_of_tags(tags)
