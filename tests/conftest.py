"""Fixtures shared by the test folders: real file systems that refuse, a tmpfs mounted read-only or nearly full
(mounted where the tests run as root, skipped elsewhere)."""

import subprocess

import pytest


def _tmpfs(tmp_path, name: str, options: str):
    """A tmpfs mounted at tmp_path/name with `options`, where this process may mount one (root); skips elsewhere."""
    mount = tmp_path / name
    mount.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(mount)], capture_output=True,
                      check=False).returncode:
        pytest.skip("cannot mount a tmpfs here")
    return mount


@pytest.fixture
def read_only_tmpfs(tmp_path):
    """A read-only tmpfs."""
    mount = _tmpfs(tmp_path, "read-only", "size=64k,ro")
    yield mount
    subprocess.run(["umount", str(mount)], check=False)


@pytest.fixture
def small_tmpfs(tmp_path):
    """A 256 kB tmpfs: a really full disk after a few frames."""
    mount = _tmpfs(tmp_path, "small", "size=256k")
    yield mount
    subprocess.run(["umount", str(mount)], check=False)
