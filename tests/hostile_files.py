"""Hostile files for the tests: checkpoints whose .npy headers lie about their size."""

import io
import zipfile

import numpy as np


def claim_terabytes(path, entry: str | None = None) -> None:
    """Rewrite the .npz at `path` so that `entry` (default: its first "params/" array) is an .npy header claiming
    10^12 float32 elements followed by 16 bytes: a file of a few kB that NumPy would try to allocate 3.64 TiB for."""
    with zipfile.ZipFile(path) as z:
        entries = {n: z.read(n) for n in z.namelist()}
    name = entry or next(n for n in entries if n.startswith("params/"))
    lie = io.BytesIO()
    np.lib.format.write_array_header_1_0(lie, {"descr": "<f4", "fortran_order": False, "shape": (10**12,)})
    entries[name] = lie.getvalue() + b"\0" * 16
    with zipfile.ZipFile(path, "w") as z:
        for n, data in entries.items():
            z.writestr(n, data)
