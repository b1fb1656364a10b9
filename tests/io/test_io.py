"""File I/O round trips (bit-exact float formats, <= 0.5 mm for 16-bit PNG) and clear errors."""

import errno
import os

import numpy as np
import pytest

from jaxsr import io
from jaxsr.app.recordings import open_recording


def depth_frame(h=16, w=24, seed=0):
    rng = np.random.default_rng(seed)
    d = rng.uniform(0.3, 60.0, (h, w)).astype(np.float32)
    d[0, :3] = np.inf  # no return
    return d


@pytest.mark.parametrize("suffix", [".exr", ".pfm", ".tif", ".tiff", ".npy"])
def test_float_formats_round_trip_bit_exact(tmp_path, suffix):
    d = depth_frame()
    path = tmp_path / f"d{suffix}"
    io.write_depth(path, d)
    back = io.read_depth(path)
    assert back.dtype == np.float32 and back.shape == d.shape
    np.testing.assert_array_equal(back.view(np.uint32), d.view(np.uint32))


def test_png_millimetres_round_trip(tmp_path):
    d = depth_frame()
    d[1, 0] = 70.0  # beyond 65.535 m: saturates
    d[1, 1] = 0.0002  # below 1 mm: stored as 1 mm
    io.write_depth(tmp_path / "d.png", d)
    back = io.read_depth(tmp_path / "d.png")
    ok = np.isfinite(d) & (d <= io.PNG_MAX_M) & (d >= 0.001)
    assert np.max(np.abs(back[ok] - d[ok])) <= 0.0005 + 1e-6
    assert np.all(np.isinf(back[~np.isfinite(d)]))
    assert back[1, 0] == pytest.approx(65.535) and back[1, 1] == pytest.approx(0.001)
    # The file really is 16-bit millimetres (read independently with OpenImageIO).
    import OpenImageIO as oiio

    buf = oiio.ImageBuf(str(tmp_path / "d.png"))
    raw = buf.get_pixels(oiio.UINT16)
    assert str(buf.spec().format) == "uint16" and raw[0, 0, 0] == 0 and raw[2, 2, 0] == round(float(d[2, 2]) * 1000)


def test_pfm_is_bottom_to_top_like_airsim(tmp_path):
    """AirSim's write_pfm flips the image and writes little-endian floats with scale -1."""
    d = depth_frame(3, 4)
    d[0, :3] = 1.0
    with open(tmp_path / "a.pfm", "wb") as f:
        f.write(b"Pf\n4 3\n-1\n")
        f.write(np.flipud(d).astype("<f4").tobytes())
    np.testing.assert_array_equal(io.read_depth(tmp_path / "a.pfm"), d)
    with open(tmp_path / "b.pfm", "wb") as f:  # big-endian (positive scale)
        f.write(b"Pf\n4 3\n1.0\n")
        f.write(np.flipud(d).astype(">f4").tobytes())
    np.testing.assert_array_equal(io.read_depth(tmp_path / "b.pfm"), d)


def test_never_overwrites_without_permission(tmp_path):
    path = tmp_path / "d.exr"
    io.write_depth(path, depth_frame())
    with pytest.raises(FileExistsError, match="overwrite"):
        io.write_depth(path, depth_frame(seed=1))
    np.testing.assert_array_equal(io.read_depth(path), depth_frame())
    io.write_depth(path, depth_frame(seed=1), overwrite=True)
    np.testing.assert_array_equal(io.read_depth(path), depth_frame(seed=1))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.exr"], "no temporary files left behind"


def test_missing_truncated_and_wrong_files_raise_clearly(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothere.exr"):
        io.read_depth(tmp_path / "nothere.exr")
    for suffix in (".exr", ".pfm", ".tif", ".png", ".npy"):
        path = tmp_path / f"d{suffix}"
        io.write_depth(path, depth_frame(64, 64))
        data = path.read_bytes()
        path.write_bytes(data[: len(data) // 2])
        with pytest.raises(ValueError, match=str(path.name)):
            io.read_depth(path)
    with pytest.raises(ValueError, match="unknown depth format"):
        io.read_depth(tmp_path / "d.jpg")
    with pytest.raises(ValueError, match="not a PFM"):
        (tmp_path / "x.pfm").write_bytes(b"P6\n1 1\n255\n\0\0\0")
        io.read_depth(tmp_path / "x.pfm")


def test_wrong_channels_and_types_raise(tmp_path):
    rgb = np.zeros((8, 8, 3), np.float32)
    io.write_image(tmp_path / "rgb.exr", rgb)
    with pytest.raises(ValueError, match="1-channel"):
        io.read_depth(tmp_path / "rgb.exr")
    io.write_image(tmp_path / "p8.png", np.zeros((8, 8), np.uint8))
    with pytest.raises(ValueError, match="16-bit"):
        io.read_depth(tmp_path / "p8.png")
    with pytest.raises(ValueError, match=r"\(H, W\)"):
        io.write_depth(tmp_path / "bad.exr", np.zeros((2, 3, 4)))
    with pytest.raises(ValueError, match="non-negative"):
        io.write_depth(tmp_path / "neg.exr", -np.ones((2, 3)))


def test_sequences_and_histograms_round_trip(tmp_path):
    from jaxsr.config import Sensor

    d = np.stack([depth_frame(seed=s) for s in range(3)])
    inten = np.random.default_rng(0).uniform(0, 1, d.shape).astype(np.float32)
    io.write_sequence(tmp_path / "s.npz", d, intensity=inten, fps=25.0, snr=1.3)
    z = io.read_sequence(tmp_path / "s.npz")
    np.testing.assert_array_equal(z["depth"], d)
    np.testing.assert_array_equal(z["intensity"], inten)
    assert z["metadata"] == dict(fps=25.0, snr=1.3)
    io.write_sequence(tmp_path / "s.npy", d)
    np.testing.assert_array_equal(io.read_sequence(tmp_path / "s.npy")["depth"], d)

    counts = np.random.default_rng(1).poisson(3.0, (3, 4, 6, 16)).astype(np.float32)
    io.write_histograms(tmp_path / "h.npz", counts, depth=d, sensor=Sensor(), snr=1.3)
    h = io.read_histograms(tmp_path / "h.npz")
    assert h["counts"].dtype == np.uint16
    np.testing.assert_array_equal(h["counts"], counts)
    assert h["config"]["optics"]["lr_shape"] == [32, 64] and h["config"]["gate"]["bin_width"] == 35.0 / 16
    assert Sensor.from_dict(h["config"]) == Sensor()  # the sensor written is the sensor read
    assert h["metadata"]["snr"] == 1.3
    with pytest.raises(ValueError, match="non-negative integers"):
        io.write_histograms(tmp_path / "bad.npz", counts + 0.5)
    (tmp_path / "t.npz").write_bytes((tmp_path / "h.npz").read_bytes()[:100])
    with pytest.raises(ValueError, match="t.npz"):
        io.read_histograms(tmp_path / "t.npz")


def test_write_image_keeps_the_pixel_type(tmp_path):
    rng = np.random.default_rng(0)
    u16 = rng.integers(0, 65536, (5, 7, 1)).astype(np.uint16)
    io.write_image(tmp_path / "a.png", u16)
    np.testing.assert_array_equal(np.rint(io.read_image(tmp_path / "a.png") * 65535), u16)
    rgb = rng.uniform(0, 1, (5, 7, 3)).astype(np.float32)
    io.write_image(tmp_path / "b.exr", rgb)
    np.testing.assert_array_equal(io.read_image(tmp_path / "b.exr"), rgb)
    with pytest.raises(FileExistsError):
        io.write_image(tmp_path / "a.png", u16)
    with pytest.raises(ValueError, match="uint8, uint16 or float32"):
        io.write_image(tmp_path / "c.png", rgb.astype(np.float64))
    with pytest.raises(ValueError, match=r"\(H, W\) or \(H, W, C\)"):
        io.write_image(tmp_path / "c.png", np.zeros((2, 3, 4, 5), np.uint8))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png", "b.exr"]


def test_read_npz_arrays_names_the_file_and_the_missing_array(tmp_path):
    np.savez(tmp_path / "a.npz", x=np.arange(3))
    np.testing.assert_array_equal(io.read_npz_arrays(tmp_path / "a.npz")["x"], np.arange(3))
    with pytest.raises(ValueError, match=r"a.npz: missing arrays \['y'\]; found \['x'\]"):
        io.read_npz_arrays(tmp_path / "a.npz", ["y"])
    with pytest.raises(FileNotFoundError, match="b.npz"):
        io.read_npz_arrays(tmp_path / "b.npz")


def test_read_npz_arrays_reads_only_the_arrays_named(tmp_path, monkeypatch):
    """The arrays a caller does not use (`jaxsr train --data` reads depth and intensity) are never
    decompressed."""
    np.savez_compressed(tmp_path / "d.npz", depth=np.ones((2, 3)), intensity=np.zeros((2, 3)), big=np.zeros(10**6))
    read = []
    real = np.lib.npyio.NpzFile.__getitem__
    monkeypatch.setattr(np.lib.npyio.NpzFile, "__getitem__", lambda self, key: read.append(key) or real(self, key))
    got = io.read_npz_arrays(tmp_path / "d.npz", ["depth"], names=("depth", "intensity"))
    assert sorted(got) == ["depth", "intensity"] and sorted(read) == ["depth", "intensity"]
    with pytest.raises(ValueError, match=r"missing arrays \['x'\]; found \['big', 'depth', 'intensity'\]"):
        io.read_npz_arrays(tmp_path / "d.npz", ["x"], names=("x",))


def _airsim_folder(tmp_path, planar, gray, stamps):
    rec = tmp_path / "rec"
    (rec / "images").mkdir(parents=True)
    lines = ["VehicleName\tTimeStamp\tPOS_X\tPOS_Y\tPOS_Z\tQ_W\tQ_X\tQ_Y\tQ_Z\tImageFile"]
    for i, (z, g, t) in enumerate(zip(planar, gray, stamps)):
        dname, sname = f"img_Drone1_0_1_{t}.pfm", f"img_Drone1_0_0_{t}.png"
        with open(rec / "images" / dname, "wb") as f:
            f.write(b"Pf\n%d %d\n-1\n" % (z.shape[1], z.shape[0]))
            f.write(np.flipud(z).astype("<f4").tobytes())
        rgb = np.stack([g, g, g], -1)
        io.write_image(rec / "images" / sname, (rgb * 255).astype(np.uint8))
        lines.append(f"Drone1\t{t}\t0\t0\t0\t1\t0\t0\t0\t{sname};{dname}")
    (rec / "airsim_rec.txt").write_text("\n".join(lines) + "\n")
    return rec


def test_read_airsim_converts_planar_to_radial(tmp_path):
    from jaxsr.config import Sensor
    from jaxsr.sensor.forward import planar_to_radial

    sensor = Sensor()
    h, w = sensor.hr_shape
    planar = [np.full((h, w), 10.0, np.float32), np.full((h, w), 12.0, np.float32)]
    gray = [np.full((h, w), 0.4, np.float32), np.full((h, w), 0.8, np.float32)]
    rec = _airsim_folder(tmp_path, planar, gray, [1000, 1040])
    out = io.read_airsim(rec, sensor=sensor)
    assert out["depth"].shape == (2, h, w)
    np.testing.assert_allclose(out["depth"][1], np.asarray(planar_to_radial(planar[1], sensor)), rtol=1e-6)
    assert out["depth"][0, 0, 0] > 10.0 and out["depth"][0, h // 2, w // 2] == pytest.approx(10.0, rel=1e-5)
    np.testing.assert_allclose(out["intensity"][0], round(0.4 * 255) / 255, atol=1e-6)
    assert out["fps"] == pytest.approx(25.0)
    with pytest.raises(FileNotFoundError, match="airsim_rec.txt"):
        io.read_airsim(tmp_path)


def test_read_airsim_without_rows_is_a_clear_error(tmp_path):
    (tmp_path / "airsim_rec.txt").write_text("VehicleName\tTimeStamp\tImageFile\n")
    with pytest.raises(ValueError, match="no frames"):
        io.read_airsim(tmp_path)


class Stop(KeyboardInterrupt):
    pass


def test_atomic_writes_leave_nothing_when_interrupted(tmp_path):
    """Ctrl-C (or SIGTERM turned into it by the `jaxsr` command) inside an atomic write removes the temporary
    file or folder; a folder's files appear under its name only once the block completes."""
    from jaxsr.io.files import atomic_folder, atomic_path

    with pytest.raises(Stop), atomic_path(tmp_path / "a.npy") as tmp:
        tmp.write_bytes(b"half")
        raise Stop
    with pytest.raises(Stop), atomic_folder(tmp_path / "new" / "frames") as tmp:
        (tmp / "f0.exr").write_bytes(b"x")
        assert tmp.parent == tmp_path and tmp.name.startswith(".frames.") and tmp.name.endswith(".partial")
        assert not (tmp_path / "new").exists()  # parents come at the end
        raise Stop
    assert list(tmp_path.iterdir()) == []
    with atomic_folder(tmp_path / "new" / "frames") as tmp:
        (tmp / "f0.exr").write_bytes(b"x")
    assert [p.name for p in (tmp_path / "new" / "frames").iterdir()] == ["f0.exr"]
    with atomic_folder(tmp_path / "new" / "frames") as tmp:  # into an existing folder: files moved in
        (tmp / "f1.exr").write_bytes(b"y")
    assert sorted(p.name for p in (tmp_path / "new" / "frames").iterdir()) == ["f0.exr", "f1.exr"]
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["f0.exr", "f1.exr", "frames", "new"]


def test_an_output_another_writer_created_meanwhile_is_never_replaced(tmp_path):
    """Two runs writing one new output both pass the check at the start; the second to finish fails, naming the
    output, and the first one's result stays (a file: a hard link that fails if the target exists; a folder: a
    rename that fails onto a folder with files). With overwrite the last one wins, as asked."""
    from jaxsr.io.files import atomic_folder, atomic_path

    out = tmp_path / "up.npy"
    with pytest.raises(FileExistsError, match=r"up\.npy was created by another writer .*not replaced"):
        with atomic_path(out) as tmp:
            tmp.write_bytes(b"second")
            out.write_bytes(b"first")  # the other run finishes meanwhile
    assert out.read_bytes() == b"first" and sorted(p.name for p in tmp_path.iterdir()) == ["up.npy"]
    with atomic_path(out, overwrite=True) as tmp:
        tmp.write_bytes(b"forced")
    assert out.read_bytes() == b"forced"

    frames = tmp_path / "frames"
    with pytest.raises(FileExistsError, match=r"frames was written by another writer .*not written into"):
        with atomic_folder(frames, overwrite=False) as tmp:
            (tmp / "frame_000000.exr").write_bytes(b"second")
            frames.mkdir()
            (frames / "frame_000000.exr").write_bytes(b"first")
    assert (frames / "frame_000000.exr").read_bytes() == b"first"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frames", "up.npy"]  # no temporary folder left
    with atomic_folder(tmp_path / "new", overwrite=False) as tmp:  # a new folder, or an empty one, is claimed
        (tmp / "a").write_bytes(b"a")
    assert (tmp_path / "new" / "a").read_bytes() == b"a"


def _disk_full(*args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def _cannot_reserve(*args, **kwargs):
    raise OSError(errno.EOPNOTSUPP, os.strerror(errno.EOPNOTSUPP))


@pytest.mark.parametrize("case", ["file", "folder", "file in a folder", "file through a file"])
def test_a_full_disk_is_a_write_error_naming_the_output_and_leaves_nothing(tmp_path, case):
    """ENOSPC (as any OSError of the disk) inside an atomic write removes the temporary file or folder and is a
    `WriteError` that names the output, never the hidden temporary (an inner write into the temporary folder or
    file names its final place)."""
    from jaxsr.io.files import WriteError, atomic_folder, atomic_path

    out = tmp_path / ("frames" if "folder" in case else "up.npz")
    want = {"file": out, "folder": out, "file in a folder": out / "h.npz", "file through a file": out}[case]
    with pytest.raises(WriteError) as caught:
        if case == "file":
            with atomic_path(out) as tmp:
                tmp.write_bytes(b"half")
                _disk_full()
        elif case == "folder":
            with atomic_folder(out) as tmp:
                (tmp / "f0.exr").write_bytes(b"x")
                _disk_full()
        elif case == "file in a folder":  # as `jaxsr simulate` writes its outputs
            with atomic_folder(out) as tmp, atomic_path(tmp / "h.npz") as inner:
                inner.write_bytes(b"half")
                _disk_full()
        else:  # as `jaxsr upscale` writes an .npz: write_sequence's own atomic write onto the temporary file
            with atomic_path(out) as tmp, atomic_path(tmp, overwrite=True) as inner:
                inner.write_bytes(b"half")
                _disk_full()
    error = caught.value
    partial = "folder" if "folder" in case else "file"
    assert error.errno == errno.ENOSPC and error.path == want
    assert str(error) == (f"no space left on device while writing {want}; nothing was written (the partial "
                          f"{partial} was removed)")
    assert list(tmp_path.iterdir()) == []


def test_user_mistakes_in_an_atomic_write_are_not_write_errors(tmp_path):
    """An existing output, a missing folder, no permission: the user's, raised as they are (exit 2 in the CLI)."""
    from jaxsr.io.files import WriteError, atomic_path

    with pytest.raises(PermissionError) as caught, atomic_path(tmp_path / "a.npy"):
        raise PermissionError(errno.EACCES, "no", "x")
    assert not isinstance(caught.value, WriteError)
    with pytest.raises(ValueError, match="mine"), atomic_path(tmp_path / "a.npy"):
        raise ValueError("mine")
    assert list(tmp_path.iterdir()) == []


def test_reserve_space_turns_a_full_disk_into_enospc_before_the_map_is_written(tmp_path, monkeypatch):
    """A memory-mapped output is created sparse; its blocks are reserved at once, so a full disk is an OSError,
    not SIGBUS when a page is written. A file system that cannot reserve is left as it is."""
    from jaxsr.io.files import reserve_space

    path = tmp_path / "m.npy"
    np.lib.format.open_memmap(path, mode="w+", dtype=np.float32, shape=(4, 1024))
    reserve_space(path)  # room enough: nothing to say
    monkeypatch.setattr(os, "posix_fallocate", _disk_full)
    with pytest.raises(OSError) as caught:
        reserve_space(path)
    assert caught.value.errno == errno.ENOSPC
    monkeypatch.setattr(os, "posix_fallocate", _cannot_reserve)
    reserve_space(path)


def test_hostile_json_metadata_of_a_recording_is_refused_or_ignored_not_a_traceback(tmp_path):
    """Metadata nested 100000 levels deep (a RecursionError in json.loads) is a ValueError naming the file
    where the metadata is read, and ignored where only its fps is looked for (`jaxsr upscale` on the recording)."""
    depth = np.full((2, 4, 4), 5.0, np.float32)
    for nested in ("[" * 100_000 + "]" * 100_000, "[" * 100 + "]" * 100):
        np.savez(tmp_path / "seq.npz", depth=depth, metadata=np.array(nested))
        with pytest.raises(ValueError, match="seq.npz: metadata: JSON metadata nested more than 64 levels"):
            io.read_sequence(tmp_path / "seq.npz")
        np.savez(tmp_path / "h.npz", counts=np.ones((1, 4, 4, 16), np.uint16), config=np.array(nested))
        with pytest.raises(ValueError, match="h.npz: config: JSON metadata nested"):
            io.read_histograms(tmp_path / "h.npz")
        rec = open_recording(tmp_path / "seq.npz")
        assert rec.fps is None and rec.frames == 2
    np.savez(tmp_path / "seq.npz", depth=depth, metadata=np.array('{"fps": 12.5, "snr": [1, [2]]}'))
    assert io.read_sequence(tmp_path / "seq.npz")["metadata"] == {"fps": 12.5, "snr": [1, [2]]}
    assert open_recording(tmp_path / "seq.npz").fps == 12.5


def _dead_pid() -> int:
    """The pid of a process that has ended."""
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    return int(done.stdout)


def test_temporaries_a_killed_writer_left_are_removed_by_the_next_write_of_that_output(tmp_path):
    """SIGKILL leaves a hidden partial file or folder that nothing removes. Its name holds the output, the
    host and the writer's pid, and the next atomic write of that output removes those of writers that no longer
    run (one warning line), never a live writer's, another host's or another output's."""
    import subprocess
    import sys

    from jaxsr.io.files import _writer_tag, atomic_folder, atomic_path

    _HOST = _writer_tag()
    dead, live = _dead_pid(), subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        left = {
            "stale file": tmp_path / f".out.{_HOST}-{dead}.k2j4h6g8.partial.npy",
            "live writer's": tmp_path / f".out.{_HOST}-{live.pid}.abcdefgh.partial.npy",
            "another host's": tmp_path / f".out.elsewhere-{dead}.abcdefgh.partial.npy",
            "another output's": tmp_path / f".out2.{_HOST}-{dead}.abcdefgh.partial.npy",
            "stale folder": tmp_path / f".frames.{_HOST}-{dead}.q1w2e3r4.partial",
        }
        for name, p in left.items():
            p.mkdir() if "folder" in name else p.write_bytes(b"half")
        (left["stale folder"] / "frame_000000.exr").write_bytes(b"x")
        with pytest.warns(UserWarning, match=rf"^removed 1 temporary file of {tmp_path / 'out.npy'} that a stopped "
                                             rf"writer left \(process {dead}, no longer running\)$"):
            with atomic_path(tmp_path / "out.npy") as tmp:
                assert tmp.name.startswith(f".out.{_HOST}-{os.getpid()}.") and tmp.name.endswith(".partial.npy")
                tmp.write_bytes(b"done")
        assert not left["stale file"].exists()
        assert all(left[k].exists() for k in ("live writer's", "another host's", "another output's"))
        with pytest.warns(UserWarning, match=r"removed 1 temporary folder of .*frames that a stopped writer left"):
            with atomic_folder(tmp_path / "frames") as tmp:
                (tmp / "frame_000000.exr").write_bytes(b"y")
        assert not left["stale folder"].exists() and (tmp_path / "frames" / "frame_000000.exr").read_bytes() == b"y"
    finally:
        live.kill()
        live.wait()


def test_only_temporaries_of_this_host_and_pid_namespace_are_removed(tmp_path, monkeypatch):
    """The writer was named by its host name cut to 24 characters and its pid: a Kubernetes pod whose name shares
    those 24 characters, or a container with this host's name and its own pids (docker --network host), could
    remove a live writer's temporary. The name now holds a hash of the full host name and the pid namespace."""
    import socket

    from jaxsr.io import files

    def tag(host, namespace):  # the writer's tag on that host, in that pid namespace
        monkeypatch.setattr(socket, "gethostname", lambda: host)
        monkeypatch.setattr(files, "_pid_namespace", lambda: namespace)
        return files._writer_tag()

    me = ("train-worker-7d9f8c6b5-0123456789-a", "4026531836")
    others = {"a pod sharing 24 characters": ("train-worker-7d9f8c6b5-0123456789-b", me[1]),
              "another pid namespace": (me[0], "4026532410")}
    dead = _dead_pid()
    left = {name: tmp_path / f".out.{tag(*other)}-{dead}.abcdefgh.partial.npy" for name, other in others.items()}
    stale = tmp_path / f".out.{tag(*me)}-{dead}.k2j4h6g8.partial.npy"
    assert len({tag(*me), *(tag(*other) for other in others.values())}) == 3
    for p in (stale, *left.values()):
        p.write_bytes(b"half")
    tag(*me)  # this writer
    with pytest.warns(UserWarning, match=rf"removed 1 temporary file of .*out.npy .*\(process {dead}, no longer"):
        with files.atomic_path(tmp_path / "out.npy") as tmp:
            assert tmp.name.startswith(f".out.{tag(*me)}-{os.getpid()}.")
            tmp.write_bytes(b"done")
    assert not stale.exists() and all(p.exists() for p in left.values())


def test_the_pid_namespace_is_the_inode_of_proc_self_ns_pid():
    from jaxsr.io.files import _pid_namespace

    if not os.path.exists("/proc/self/ns/pid"):
        pytest.skip("no /proc/self/ns/pid on this system")
    assert _pid_namespace() == str(os.stat("/proc/self/ns/pid").st_ino) != ""


def _fail_with(number):
    def fail(*args, **kwargs):
        raise OSError(number, os.strerror(number), os.path.join(kwargs.get("dir") or ".", ".tmp"))

    return fail


@pytest.mark.parametrize("number,reason", [(errno.EACCES, "permission denied"), (errno.EROFS, "read-only file system")])
@pytest.mark.parametrize("kind", ["file", "folder"])
def test_a_folder_that_cannot_be_written_into_is_the_users_and_names_the_output(tmp_path, monkeypatch, number,
                                                                                reason, kind):
    """A read-only output folder was an OSError traceback. As root, chmod does not refuse a write, so the
    system's refusal is injected where the temporary is created: a `NotWritableError` (a PermissionError: exit 2 in
    the CLI) naming the output, nothing left."""
    import tempfile

    from jaxsr.io.files import NotWritableError, WriteError, atomic_folder, atomic_path

    out = tmp_path / ("frames" if kind == "folder" else "out.npy")
    monkeypatch.setattr(tempfile, "mkdtemp" if kind == "folder" else "mkstemp", _fail_with(number))
    with pytest.raises(NotWritableError) as caught:
        with (atomic_folder if kind == "folder" else atomic_path)(out):
            pass
    assert isinstance(caught.value, PermissionError) and not isinstance(caught.value, WriteError)
    assert str(caught.value) == f"cannot write {out}: {reason}; choose a folder you can write to"
    assert list(tmp_path.iterdir()) == []


def test_a_read_only_file_system_met_in_a_write_is_not_writable_whatever_file_it_names(tmp_path):
    """EROFS that named no file (a write through an open file) or another file the block wrote was a WriteError
    (exit 1), unlike the same error naming the temporary (exit 2): a read-only file system is the user's choice of
    place wherever it is met. A PermissionError naming another file (perhaps one the block read) is its own."""
    from pathlib import Path

    from jaxsr.io.files import NotWritableError, WriteError, atomic_path

    out = tmp_path / "out.npy"
    for name, want in [(None, out), ("/elsewhere/x.npy", Path("/elsewhere/x.npy"))]:
        with pytest.raises(NotWritableError) as caught, atomic_path(out):
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), *([] if name is None else [name]))
        assert caught.value.path == want and str(caught.value) == (f"cannot write {want}: read-only file system; "
                                                                   "choose a folder you can write to")
    with pytest.raises(PermissionError) as caught, atomic_path(out):
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), "/elsewhere/input.npy")
    assert not isinstance(caught.value, (NotWritableError, WriteError))
    assert list(tmp_path.iterdir()) == []


def test_check_output_folder_checks_the_folder_above_and_an_existing_folder(tmp_path, monkeypatch):
    """One check for every output folder (`jaxsr upscale`'s OUTPUT, `jaxsr simulate --out`, `--points`): the
    point clouds' folder checked only the folder above it, so an existing one that cannot be written failed at
    the end of the work."""
    from pathlib import Path

    from jaxsr.io.files import NotWritableError, check_output_folder
    from jaxsr.io.pointcloud import check_points_folder
    from jaxsr.app.outputs import check_output
    from jaxsr.app.simulate import _check_out

    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "old.txt").write_text("x")
    check_output_folder(tmp_path / "out")
    check_output_folder(tmp_path / "new" / "deeper")
    refused = {tmp_path / "out"}
    monkeypatch.setattr(os, "access", lambda path, mode: Path(os.path.abspath(path)) not in refused)
    for check in (check_output_folder, lambda p: check_output(p, force=True), lambda p: _check_out(p, True),
                  lambda p: check_points_folder(p, force=True)):
        with pytest.raises(NotWritableError, match=rf"^cannot write {tmp_path / 'out'}: {tmp_path / 'out'} is not "
                                                   "writable"):
            check(tmp_path / "out")
    refused = {tmp_path}  # where a new folder's hidden temporary goes
    with pytest.raises(NotWritableError, match=rf"^cannot write {tmp_path / 'new' / 'deeper'}: {tmp_path} is not"):
        check_output_folder(tmp_path / "new" / "deeper")


def test_check_writable_refuses_a_folder_this_process_cannot_write_into(tmp_path, monkeypatch):
    """Before any work (`jaxsr upscale` checks its outputs' folders with it): os.access, which reports a read-only
    file system to root too, injected here."""
    from jaxsr.io.files import NotWritableError, check_writable

    check_writable(tmp_path, tmp_path / "out.npy")
    monkeypatch.setattr(os, "access", lambda path, mode: False)
    with pytest.raises(NotWritableError, match=rf"^cannot write {tmp_path / 'out.npy'}: {tmp_path} is not writable; "
                                               "choose a folder you can write to$"):
        check_writable(tmp_path, tmp_path / "out.npy")


def test_no_memory_for_an_npz_recording_is_not_called_a_damaged_file(tmp_path, monkeypatch):
    """A MemoryError while an .npz's array is read was "truncated or not an NPZ file" (exit 2, blaming the file):
    the machine's fault goes through as it is; a damaged array is still named so."""
    from jaxsr.app.recordings import open_recording

    np.savez(tmp_path / "d.npz", depth=np.full((2, 8, 8), 0.5, np.float32))

    def no_memory(*args, **kwargs):
        raise MemoryError("Unable to allocate 4.00 GiB")

    real_load = np.load
    monkeypatch.setattr(np.lib.npyio.NpzFile, "__getitem__", no_memory)  # the array
    with pytest.raises(MemoryError):
        open_recording(tmp_path / "d.npz")
    monkeypatch.setattr(np, "load", no_memory)  # the archive's directory
    with pytest.raises(MemoryError):
        open_recording(tmp_path / "d.npz")
    monkeypatch.undo()
    (tmp_path / "d.npz").write_bytes((tmp_path / "d.npz").read_bytes()[:-200])
    assert np.load is real_load
    with pytest.raises(ValueError, match="truncated or not an NPZ file"):
        open_recording(tmp_path / "d.npz")


def test_frames_are_checked_in_blocks_of_bounded_memory(tmp_path):
    """`check_frames` read 256 frames at a time as float64, whatever their size (4 GB for frames of
    1024 x 1024 pixels); now blocks of at most `CHECK_BLOCK_BYTES`, and at least one frame."""
    from jaxsr.app.recordings import CHECK_BLOCK_BYTES, _chunks, open_recording

    np.save(tmp_path / "big.npy", np.zeros((40, 512, 512), np.float32))
    blocks = [block for _, block in _chunks(open_recording(tmp_path / "big.npy"))]
    assert max(b.nbytes for b in blocks) <= CHECK_BLOCK_BYTES and sum(len(b) for b in blocks) == 40
    np.save(tmp_path / "huge.npy", np.zeros((2, 3000, 3000), np.float32))
    assert [len(b) for _, b in _chunks(open_recording(tmp_path / "huge.npy"))] == [1, 1]


def test_files_that_are_not_npy_or_npz_are_named_so_without_numpys_pickle_advice(tmp_path):
    """Random bytes, text or an empty file given as .npy, or as a model's .npz: a ValueError saying what the file
    is not; numpy alone would take them for pickles and suggest `allow_pickle`."""
    from jaxsr.io.checkpoint import load_model
    from jaxsr.io.formats import load_npy

    for name, data in {"bytes.npy": bytes(range(256)), "text.npy": b"1,2,3\n", "empty.npy": b""}.items():
        (tmp_path / name).write_bytes(data)
        with pytest.raises(ValueError, match="not an NPY file") as e:
            load_npy(tmp_path / name)
        assert "allow_pickle" not in str(e.value)
    np.save(tmp_path / "ok.npy", np.arange(3.0))
    (tmp_path / "cut.npy").write_bytes((tmp_path / "ok.npy").read_bytes()[:-8])
    with pytest.raises(ValueError, match="truncated or damaged"):
        load_npy(tmp_path / "cut.npy")
    np.testing.assert_array_equal(load_npy(tmp_path / "ok.npy", mmap_mode="r"), np.arange(3.0))
    (tmp_path / "m.npz").write_bytes(bytes(range(256)))
    with pytest.raises(ValueError, match="not an .npz file") as e:
        load_model(tmp_path / "m.npz")
    assert "allow_pickle" not in str(e.value)


def test_reading_an_npz_that_inflates_beyond_the_budget_is_refused_before_it_is_read(tmp_path):
    """A few kB of zeros that inflate to 400 MB: refused from the headers under a 100 MB budget, read under the
    default."""
    np.savez_compressed(tmp_path / "h.npz", counts=np.zeros((100, 256, 256, 16), np.uint8))
    assert (tmp_path / "h.npz").stat().st_size < 2e6
    with pytest.raises(ValueError, match=r"h.npz: its arrays counts needs about 105 MB of memory, more than the"):
        io.read_histograms(tmp_path / "h.npz", max_memory="100MB")
    np.savez_compressed(tmp_path / "s.npz", depth=np.zeros((100, 512, 512), np.float32))
    with pytest.raises(ValueError, match="needs about 105 MB of memory"):
        io.read_sequence(tmp_path / "s.npz", max_memory="50MB")


def test_reading_an_npy_sequence_beyond_the_budget_is_refused_from_its_header(tmp_path):
    """read_sequence read an .npy whole whatever its size: now sized from its header first, as an .npz is; a
    header claiming more than the file holds is a damaged file, not an allocation."""
    np.save(tmp_path / "s.npy", np.zeros((100, 512, 512), np.float32))
    with pytest.raises(ValueError, match=r"s.npy: its array needs about 105 MB of memory, more than the 50 MB"):
        io.read_sequence(tmp_path / "s.npy", max_memory="50MB")
    assert io.read_sequence(tmp_path / "s.npy", max_memory="200MB")["depth"].shape == (100, 512, 512)
    with open(tmp_path / "lies.npy", "wb") as f:  # a header for 10^12 floats, then 16 bytes
        np.lib.format.write_array_header_1_0(f, {"descr": "<f4", "fortran_order": False,
                                                 "shape": (10**4, 10**4, 10**4)})
        f.write(bytes(16))
    with pytest.raises(ValueError, match="lies.npy: a truncated or damaged NPY file"):
        io.read_sequence(tmp_path / "lies.npy")
