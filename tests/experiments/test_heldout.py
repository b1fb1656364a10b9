"""The held-out benchmark (experiments/studies/_heldout_data.py, heldout.py) on tiny synthetic stand-ins of its
sources: the unit rules of each format, the radial conversion against the library's, the resampling, a prepare
run from a git repository, the measures and the report. The real data is not needed; the test that reads it
skips where it is absent."""

import io
import json
import os
import subprocess
from pathlib import Path
from types import SimpleNamespace

import jax
import numpy as np
import pytest
from PIL import Image

import heldout  # experiments/studies (pytest's pythonpath)
import _heldout_data as hd
import _photon_benchmark as bench
from jaxsr.config import MODEL_INPUTS, ModelConfig, Sensor
from jaxsr.nn import Model, init_model
from jaxsr.sensor.forward import planar_to_radial


def png16(a) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(np.asarray(a, np.uint16)).save(buf, format="PNG")
    return buf.getvalue()


def png_rgb(a) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(np.asarray(a, np.uint8)).save(buf, format="PNG")
    return buf.getvalue()


# ------------------------------------------------------------------------------------------------ unit rules

def test_nyu_disparity_bytes_and_formula():
    raw = np.array([[600, 1000, 2047]])
    # the file's 16-bit words are little-endian behind a PGM header (which says big-endian): Open3D swaps them
    body = raw.astype("<u2").tobytes()
    data = b"P5 3 1 65535\n" + body
    metres = hd.nyu_metres(data)
    np.testing.assert_allclose(metres[0, :2], 351.3 / (1092.5 - raw[0, :2]))
    assert metres[0, 2] == 0.0  # 2047: no measurement


def test_tum_and_sun_units():
    np.testing.assert_allclose(hd.tum_metres(png16([[5000, 12500, 0]])), [[1.0, 2.5, 0.0]])
    mm = np.array([[1500, 8191, 0]], np.uint32)
    stored = ((mm << 3) | (mm >> 13)) & 0xFFFF  # SUN RGB-D's rotation of the millimetres
    np.testing.assert_allclose(hd.sun_metres(png16(stored)), mm / 1000.0)


def test_radial_matches_the_library_at_its_own_camera():
    sensor = Sensor()
    h, w = sensor.hr_shape
    f = (w / 2) / np.tan(np.deg2rad(15.0))  # docs/sensor-model.md: 30 deg horizontal field of view
    z = np.random.default_rng(0).uniform(1.0, 30.0, (h, w))
    # OpenCV's principal point of the centre (col = u) is (w - 1) / 2; jaxsr's pixel centres are col + 0.5
    ours = hd.to_radial(z, (f, f, (w - 1) / 2, (h - 1) / 2))
    np.testing.assert_allclose(ours, np.asarray(planar_to_radial(z, sensor)), rtol=1e-5)


def test_fill_missing_takes_the_nearest_measured_pixel():
    d = np.array([[2.0, 0.0, 0.0, 5.0], [2.0, np.nan, 0.0, 5.0]])
    np.testing.assert_array_equal(hd.fill_missing(d), [[2.0, 2.0, 5.0, 5.0], [2.0, 2.0, 5.0, 5.0]])
    with pytest.raises(ValueError, match="at least one measured pixel"):
        hd.fill_missing(np.zeros((2, 2)))


def test_resampling_invents_no_depth_and_crops_the_middle():
    d = np.random.default_rng(1).choice([1.5, 7.0, 20.0], size=(48, 64))
    out = hd.resample_depth(hd.crop_rows(d, 2.0), (8, 16))
    assert out.shape == (8, 16) and set(np.unique(out)) <= {1.5, 7.0, 20.0}
    assert hd.crop_rows(d, 2.0).shape == (32, 64)
    np.testing.assert_array_equal(hd.crop_rows(d, 2.0), d[8:40])
    grey = hd.intensity_of(np.full((32, 64, 3), 255, np.uint8), (8, 16))
    np.testing.assert_allclose(grey, 1.0)


# ------------------------------------------------------------------------------------------------ prepare

def fake_open3d(root: Path) -> str:
    """A git repository holding a TUM-format depth (a plane 2 m ahead with a hole) and colour frame at the paths of
    _heldout_data.SETS["tum-desk"]; returns its commit."""
    src = hd.SETS["tum-desk"]
    depth = np.full((480, 640), 2.0 * 5000, np.uint16)  # the size its Kinect intrinsics are for
    depth[200:240, 300:340] = 0  # a hole: no measurement
    color = np.zeros((480, 640, 3), np.uint8)
    color[:, 320:] = 200
    for path, data in ((src.depth[0], png16(depth)), (src.color[0], png_rgb(color))):
        (root / path).parent.mkdir(parents=True, exist_ok=True)
        (root / path).write_bytes(data)
    env = {**os.environ, "GIT_AUTHOR_NAME": "t", "GIT_AUTHOR_EMAIL": "t@t", "GIT_COMMITTER_NAME": "t",
           "GIT_COMMITTER_EMAIL": "t@t"}
    run = lambda *a: subprocess.run(["git", "-C", str(root), *a], check=True, capture_output=True, env=env)  # noqa: E731
    run("init", "-q")
    run("add", ".")
    run("commit", "-qm", "frames")
    return run("rev-parse", "HEAD").stdout.decode().strip()


def test_prepare_from_a_git_repository_and_load(tmp_path, monkeypatch):
    repo = tmp_path / "open3d"
    repo.mkdir()
    commit = fake_open3d(repo)
    bare = tmp_path / "mirror.git"
    subprocess.run(["git", "clone", "-q", "--bare", str(repo), str(bare)], check=True)
    # read at the commit the set names (here the fake repository's), from the bare mirror: no work tree
    monkeypatch.setitem(hd.SETS, "tum-desk", hd.dataclasses.replace(hd.SETS["tum-desk"], commit=commit))
    data = tmp_path / "data"
    manifest = hd.prepare({hd.OPEN3D: bare}, data, names=["tum-desk"], static_frames=5, log=lambda _: None)
    scenes = hd.load_scenes(data)
    seq = scenes["tum-desk"]
    h, w = Sensor().hr_shape
    assert seq.depth.shape == seq.intensity.shape == (5, h, w) and seq.kind == "static" and seq.snr == 1.3
    np.testing.assert_array_equal(seq.depth[0], seq.depth[4])  # a still scene
    # a plane 2 m ahead: radial range 2 m at the principal point, more towards the corners (the crop's corner ray,
    # 320 and 160 pixels off at f = 525, 1.17 times as long); the hole filled
    corner = 2.0 * np.sqrt(1 + (319.5 / 525) ** 2 + (159.5 / 525) ** 2)
    assert 2.0 <= seq.depth.min() < 2.001 and seq.depth.max() == pytest.approx(corner, rel=0.01)
    assert np.isfinite(seq.depth).all()
    assert seq.intensity[0, :, : w // 2 - 2].max() == 0.0 and seq.intensity[0, :, w // 2 + 2:].min() > 0.7
    assert manifest["tum-desk"]["commit"] == commit and manifest["tum-desk"]["beyond_gate_pct"] == 0.0
    assert json.loads((data / "manifest.json").read_text()) == manifest
    with pytest.raises(ValueError, match="unknown set"):
        hd.prepare({hd.OPEN3D: bare}, data, names=["nope"])
    with pytest.raises(FileNotFoundError, match="expected a checkout or git mirror"):
        hd.read_blob(tmp_path, "missing.png", commit)
    with pytest.raises(FileNotFoundError, match="no held-out scenes"):
        hd.load_scenes(tmp_path / "empty")


# ------------------------------------------------------------------------------------------------ the measures

def test_shares_count_returns_away_from_edges_and_sky_shown_as_depth():
    gt = np.full((1, 10, 10), 0.3, np.float32)
    gt[0, :, 7:] = 1.0  # no return on the right
    inner = bench.away_from_edges(gt)[0]
    assert inner[:, :6].all() and not inner[:, 6:].any()  # column 6 touches the sky
    sr = gt.copy()
    sr[0, 2, 2] = 1.0  # a dropped return away from the edges
    sr[0, 5, 6] = 1.0  # one at the edge: not counted
    sr[0, 0, 9] = 0.5  # sky shown as depth
    sr[0, 1, 9] = np.nan  # NaN: no return
    dropped, shown, n_ret, n_sky = bench.shares(sr, gt)
    assert (n_ret, n_sky) == (60, 30)
    assert dropped == pytest.approx(100.0 / 60) and shown == pytest.approx(100.0 / 30)


def test_regimes_run_the_issues_first():
    grid = heldout.regimes([1.0, 3.0, 14.0], [0.1, 1.3, 5.0])
    first = [(p, s) for p in (3.0, 14.0) for s in (1.3, 0.3, 0.1)]
    assert grid[:6] == first
    assert sorted(grid[:-1]) == sorted(set(first) | {(p, s) for p in (1.0, 3.0, 14.0) for s in (0.1, 1.3, 5.0)})
    assert grid[-1][1] is None  # the paper's: each scene's own SNR


def test_summary_pools_the_shares_by_pixel_counts():
    grid = [(3.0, 1.3)]
    entry = lambda psnr, dropped, n: {**{m: {"psnr": [psnr], "dropped_pct": dropped, "as_depth_pct": float("nan")}  # noqa: E731
                                         for m in heldout.METHODS}, "returns": n, "no_return": 0}
    cache = {heldout.cache_key("g", "a", 3.0, 1.3, 2): entry(20.0, 1.0, 100),
             heldout.cache_key("g", "b", 3.0, 1.3, 2): entry(30.0, 4.0, 300)}
    rows = heldout.summary(cache, {"g": {"a": None, "b": None}}, grid, {"g": 2})
    g = rows[0]["groups"]["g"][heldout.UPSCALE]
    assert g["psnr"] == pytest.approx(25.0) and g["dropped_pct"] == pytest.approx((1.0 * 100 + 4.0 * 300) / 400)
    assert np.isnan(g["as_depth_pct"])
    text = heldout.tables(rows, {"g": {"a": None, "b": None}})
    assert "+0.00" in text and "3.250" in text  # default - TR4; the pooled share


def tiny(cfg):
    return Model(*init_model(jax.random.key(0), cfg), cfg)


def synthetic_sequence(frames=6):
    h, w = Sensor().hr_shape
    depth = np.broadcast_to(np.linspace(30.0, 5.0, h, dtype=np.float32)[:, None], (frames, h, w)).copy()
    depth[:, :10] = np.inf  # a band of sky
    return SimpleNamespace(depth=depth, intensity=np.full_like(depth, 0.5), fps=30.0, snr=1.3)


def tiny_models():
    small = dict(base=8, growth=4, head=16, filter_hidden=16, same_blocks=1)
    head = tiny(ModelConfig(tr=0, inputs=MODEL_INPUTS, no_return_head=True, **small))
    # jaxsr.upscale runs the same network as the keep rule's: what differs is the decision alone
    return {heldout.PAPER_TR4: tiny(ModelConfig(tr=0, **small)), heldout.KEEP: head, heldout.UPSCALE: head}


@pytest.mark.slow  # compiles two small networks, the photon draw and jaxsr.upscale: about 30 s on 2 cores
def test_score_scene_on_a_synthetic_sequence():
    seq = synthetic_sequence()
    w = seq.depth.shape[-1]
    out = heldout.score_scene(tiny_models(), "synthetic", seq, 3.0, 1.3, frames=2)
    assert set(out) == set(heldout.METHODS) | {"returns", "no_return"}
    assert out["no_return"] == 2 * 10 * w  # the sky band over the two scored frames
    for m in heldout.METHODS:
        assert len(out[m]["psnr"]) == 2 and np.isfinite(out[m]["psnr"]).all()
        assert 0.0 <= out[m]["dropped_pct"] <= 100.0 and 0.0 <= out[m]["as_depth_pct"] <= 100.0
    # one method alone reads the same photons as with the others
    alone = heldout.score_scene(tiny_models(), "synthetic", seq, 3.0, 1.3, frames=2, methods=(heldout.UPSCALE,))
    assert set(alone) == {heldout.UPSCALE, "returns", "no_return"}
    assert alone[heldout.UPSCALE] == out[heldout.UPSCALE]


@pytest.mark.slow  # compiles a small network, the photon draw and jaxsr.upscale: about 20 s on 2 cores
def test_upscale_default_reads_the_benchmark_sensor():
    # jaxsr.upscale of the simulated counts puts depth on the benchmark's scale (16 bins over 0-35 m, span 35 m):
    # where it and the keep rule both output depth from the same network, the two are the same numbers
    seq = synthetic_sequence(9)
    models = tiny_models()
    keep = ("keep", float(heldout.AUTO_KEEP_RETURNS))
    clips, flags = heldout.benchmark_clips({"s": seq}, 14.0, 1.3, scored=np.array([4]), radius=0,
                                           key=jax.random.key(1), tests=(keep,), counts=True)
    clip = clips["s"]
    assert clip.counts.shape == (9, *Sensor().lr_shape, Sensor().bins)
    out = heldout.method_outputs(models, clip, flags["s"][keep], (heldout.KEEP, heldout.UPSCALE))
    (kept, gt), (user, gt2) = out[heldout.KEEP], out[heldout.UPSCALE]
    np.testing.assert_array_equal(gt, gt2)
    both = (kept < bench.NO_RETURN_AT) & (user < bench.NO_RETURN_AT)
    assert both.mean() > 0.5
    np.testing.assert_allclose(user[both], np.clip(kept[both], 0.0, 1.0), atol=1e-4)  # normalised units: clipped
    without = heldout.benchmark_clips({"s": seq}, 14.0, 1.3, scored=np.array([4]), radius=0,
                                      key=jax.random.key(1), tests=(keep,))[0]["s"]
    with pytest.raises(ValueError, match="without its photon counts"):
        heldout.upscale_output("default", without)


def test_run_reuses_the_cache_of_the_methods_before(tmp_path, monkeypatch):
    # a cache written before jaxsr.upscale's default was scored: its "default" is the keep rule's; only the new
    # method is scored, under a key of its own, and the old entry is read under the name the keep rule has now
    key = heldout.cache_key("g", "a", 3.0, 1.3, 2)
    scores = {"psnr": [20.0], "dropped_pct": 1.0, "as_depth_pct": 0.0, "dropped_error_pct": 50.0}
    old = {key: {"bicubic": scores, "paper's TR4": scores, "default": {**scores, "psnr": [21.0]},
                 "returns": 10, "no_return": 0}}
    path = tmp_path / "heldout.cache.json"
    path.write_text(json.dumps(old))
    asked = []

    def score_scene(models, name, seq, p, s, *, frames, seed, methods):
        asked.append(tuple(methods))
        return {**{m: {**scores, "psnr": [25.0]} for m in methods}, "returns": 10, "no_return": 0}

    monkeypatch.setattr(heldout, "score_scene", score_scene)
    cache = heldout.run({}, {"g": {"a": None}}, [(3.0, 1.3)], frames={"g": 2}, cache_path=path, log=lambda _: None)
    assert asked == [(heldout.UPSCALE,)]
    assert cache[key][heldout.KEEP] == old[key]["default"] and "default" not in cache[key]
    assert set(json.loads(path.read_text())) == {key, heldout.slot(key, heldout.UPSCALE)}
    row = heldout.summary(heldout.load_cache(path), {"g": {"a": None}}, [(3.0, 1.3)], {"g": 2})[0]["groups"]["g"]
    assert row[heldout.KEEP]["psnr"] == 21.0 and row[heldout.UPSCALE]["psnr"] == 25.0
    heldout.run({}, {"g": {"a": None}}, [(3.0, 1.3)], frames={"g": 2}, cache_path=path, log=lambda _: None)
    assert len(asked) == 1  # all cached: nothing scored again


# ------------------------------------------------------------------------------------------------ the real data

DATA = Path(os.environ.get("JAXSR_HELDOUT", hd.DEFAULT_DATA))


@pytest.mark.skipif(not (DATA / "manifest.json").is_file(),
                    reason=f"the held-out data is not in {DATA} (experiments/studies/heldout.py prepare writes it; "
                           "JAXSR_HELDOUT names another folder)")
def test_the_prepared_held_out_scenes():
    manifest = json.loads((DATA / "manifest.json").read_text())
    scenes = hd.load_scenes(DATA)
    assert scenes and set(scenes) <= set(manifest)
    for name, seq in scenes.items():
        assert seq.depth.shape[1:] == Sensor().hr_shape == seq.intensity.shape[1:]
        assert np.isfinite(seq.intensity).all() and 0.0 <= seq.intensity.min() and seq.intensity.max() <= 1.0
        assert (seq.depth > 0).all(), name
        if seq.kind == "static":
            assert (seq.depth == seq.depth[:1]).all()


@pytest.mark.slow  # compiles the calibration and the rates: seconds on 2 cores
def test_dim_returns_in_closed_form():
    # two planes of equal reflectivity, 5 m on the left and 20 m on the right: signal goes as 1 / r^2, so at a
    # mean of 3 photons per LR pixel the near half gets 2 * 3 * 400 / 425 = 5.65 and the far half 0.35
    h, w = Sensor().hr_shape
    depth = np.full((2, h, w), 5.0, np.float32)
    depth[:, :, w // 2:] = 20.0
    seq = SimpleNamespace(depth=depth, intensity=np.full_like(depth, 0.5))
    d = heldout.dim_returns(seq, 3.0, 1.3, every=1)
    assert d["dim_pct"] == pytest.approx(50.0)
    near, far = (1 - 5.0 / 35) ** 2, (1 - 20.0 / 35) ** 2
    assert d["cost"] == pytest.approx((near + far) / 2, rel=1e-5)
    assert d["dim_cost"] == pytest.approx(far, rel=1e-5)


def test_dropped_error_is_the_share_of_squared_error_on_dropped_returns():
    gt = np.array([[[0.2, 0.2, 0.5, 1.0]]])
    sr = np.array([[[1.0, 0.3, np.nan, 0.4]]])  # a return dropped, one off by 0.1, NaN: dropped, sky as depth
    err = [0.8 ** 2, 0.1 ** 2, 0.5 ** 2, 0.6 ** 2]
    assert bench.dropped_error(sr, gt) == pytest.approx(100 * (err[0] + err[2]) / sum(err))
    assert np.isnan(bench.dropped_error(gt, gt))


def test_regime_keys_differ_and_take_1000_photons():
    keys = [bench.regime_key(0, p, s) for p in (1.0, 14.0, 1000.0) for s in (0.1, 5.0, None)]
    data = {tuple(np.asarray(jax.random.key_data(k)).ravel()) for k in keys}
    assert len(data) == len(keys)  # one noise per regime, 1000 photons within fold_in's 32 bits
