"""experiments/studies/real_photons.py: the photon video's splitting and thinning on synthetic time tags (frames
disjoint, levels kept, the recording's photons capping the frames), the reference's test for a rivalling second
return, and the script's core on crops of the real recordings (skipped where they are absent)."""

import json

import numpy as np
import pytest

import jaxsr
import real_photons  # experiments/studies (pytest's pythonpath)
from jaxsr.sensor.timetags import TimeTags


def synthetic_tags(n=5000, side=16, seed=0):
    """n photons on a side x side grid, pixel p drawn with weight 1 + p (bright and dark pixels), each with a
    unique arrival time (its index), so that a photon can be followed through the split."""
    rng = np.random.default_rng(seed)
    weights = 1.0 + np.arange(side * side)
    pixel = rng.choice(side * side, n, p=weights / weights.sum())
    return TimeTags(pixel.astype(np.int64), np.zeros(n, np.int64), np.arange(n, dtype=np.float64), (side, side), 1,
                    1e-12, "synthetic")


def test_bin_pixels_maps_blocks_to_lr_pixels():
    tags = synthetic_tags(n=2000)
    lr = real_photons.bin_pixels(tags)
    y, x = np.divmod(tags.pixel, 16)
    assert lr.shape == (4, 4)
    np.testing.assert_array_equal(lr.pixel, (y // 4) * 4 + x // 4)
    np.testing.assert_array_equal(lr.time, tags.time)


@pytest.mark.parametrize("level", [1.0, 2.0, 16.0])
def test_photon_video_frames_disjoint_at_the_level(level):
    lr = real_photons.bin_pixels(synthetic_tags())
    video = real_photons.photon_video(lr, level, max_frames=9, seed=3)
    per_frame = round(level * 16)
    assert video.frames == min(9, 5000 // per_frame)  # 16 photons: 19 frames' worth, capped at 9
    assert np.all(np.bincount(video.frame, minlength=video.frames) == per_frame)  # exactly L per LR pixel, mean
    assert len(np.unique(video.time)) == video.time.size  # no photon in two frames
    assert np.isin(video.time, lr.time).all()
    # each photon keeps its LR pixel
    np.testing.assert_array_equal(video.pixel, lr.pixel[video.time.astype(int)])


def test_photon_video_caps_frames_and_thins_evenly():
    lr = real_photons.bin_pixels(synthetic_tags())
    # 5000 photons over 16 LR pixels: 312 per pixel; 100 per pixel and frame leaves room for 3 frames, 400 none
    assert real_photons.photon_video(lr, 100.0, max_frames=9, seed=0).frames == 3
    assert real_photons.photon_video(lr, 400.0, max_frames=9, seed=0) is None
    # seeded: the same split for the same seed, another for another
    a, b, c = (real_photons.photon_video(lr, 4.0, max_frames=9, seed=s) for s in (1, 1, 2))
    np.testing.assert_array_equal(a.time, b.time)
    np.testing.assert_array_equal(a.frame, b.frame)
    assert not np.array_equal(a.time, c.time)
    # thinning: each LR pixel's share of a frame follows its share of the recording (bright pixels keep more)
    video = real_photons.photon_video(lr, 30.0, max_frames=9, seed=0)
    kept = np.bincount(video.pixel, minlength=16) / video.time.size
    whole = np.bincount(lr.pixel, minlength=16) / lr.time.size
    np.testing.assert_allclose(kept, whole, atol=0.01)


def test_split_photons_labels():
    label = real_photons.split_photons(10, 3, max_frames=5, seed=0)
    assert sorted(label.tolist()) == [-1, 0, 0, 0, 1, 1, 1, 2, 2, 2]
    assert (real_photons.split_photons(10, 3, max_frames=1, seed=0) >= 0).sum() == 3
    with pytest.raises(ValueError):
        real_photons.split_photons(10, 0, max_frames=1, seed=0)


def test_competing_return():
    counts = np.zeros((4, 16))
    counts[0, 3] = 20  # one return on a dark background
    counts[1, [3, 10]] = 20, 18  # two returns of about equal strength: which is highest is chance
    counts[2, [3, 10]] = 60, 10  # a second return the peak beats clearly
    counts[3, [3, 4]] = 20, 18  # both in the peak's window: one return
    np.testing.assert_array_equal(real_photons.competing_return(counts), [False, True, False, False])


DATA = real_photons.DEFAULT_DATA


def test_near_gaps_and_the_psnr_split():
    """near_gaps: the valid pixels whose LR block or one of its 8 neighbours holds a pixel without a reference;
    psnr_near and psnr_away split the valid pixels' squared error between them."""
    valid = np.ones((16, 16), bool)  # 4 x 4 LR blocks of 4 x 4
    valid[0, 0] = False  # a gap in LR block (0, 0): its block and the three beside it are near
    near = real_photons.near_gaps(valid)
    expected = np.zeros((16, 16), bool)
    expected[:8, :8] = True
    np.testing.assert_array_equal(near, expected & valid)
    rng = np.random.default_rng(0)
    ref = rng.uniform(0.2, 0.8, (16, 16))
    sr = ref[None] + rng.normal(0, 0.05, (2, 16, 16))
    s = real_photons.masked_scores(sr, ref, valid, near=near)
    share = near[valid].mean()
    mse = lambda db: 10 ** (-np.asarray(db) / 10)  # noqa: E731  peak 1
    np.testing.assert_allclose(mse(s["psnr"]), share * mse(s["psnr_near"]) + (1 - share) * mse(s["psnr_away"]),
                               rtol=1e-4)
    assert np.isnan(real_photons.masked_scores(sr, ref, valid)["psnr_near"]).all()


@pytest.mark.skipif(not all((DATA / s.file).is_file() for s in real_photons.SOURCES[:2]),
                    reason=f"the real recordings (tower.mat, two_layer.mat) are not in {DATA}; they are not part of "
                           "the project (docs/own-sensor.md, 'Real recordings', says where to get them)")
@pytest.mark.slow  # 8-32 s on 2 cores: keeps the default suite under 8 minutes
def test_core_on_crops_of_the_real_recordings(tmp_path):
    recordings = [real_photons.read_recording(DATA, real_photons.SOURCES[0], crop=(64, 64, 48)),
                  real_photons.read_recording(DATA, real_photons.SOURCES[1], crop=(24, 24, 48))]
    assert [r.tags.shape for r in recordings] == [(48, 48), (48, 48)]
    # the bundled TR0, labelled TR4 so that the goal (TR4 against bicubic) has its model: it compiles faster
    # and the same with the no-return decisions applied (only adds no return; the same model: no new compile)
    models = {"TR4": jaxsr.load_model("tr0")}
    models.update({"TR4+test": models["TR4"], "TR4+shares": models["TR4"]})
    results = real_photons.evaluate(recordings, models, levels=[2.0], max_frames=2, log=lambda _: None,
                                    ambient={"TR4+test": 1e-3, "TR4+shares": ("shares", 1e-3)})
    for rec in recordings:
        r = results[rec.name]
        assert r["lr_shape"] == (12, 12) and r["valid"].any()
        assert 0 < r["noise"]["both_return"] <= 1 and np.isfinite(r["noise"]["psnr_halves"])
        (entry,) = r["levels"]
        assert entry["frames"] == 2
        assert set(entry["scores"]) == {"nearest", "bicubic", "TV", "TR4", "TR4+test", "TR4+shares"}
        plain = entry["scores"]["TR4"]
        for decided in ("TR4+test", "TR4+shares"):
            assert np.all(entry["scores"][decided]["no_return"] >= plain["no_return"])
            assert np.all(np.nan_to_num(entry["scores"][decided]["sky_as_depth"], nan=0.0)
                          <= np.nan_to_num(plain["sky_as_depth"], nan=0.0))
        for s in entry["scores"].values():
            assert s["psnr"].shape == (2,) and np.all(np.isfinite(s["psnr"]))
            assert np.all((s["no_return"] >= 0) & (s["no_return"] <= 1))
            sky = s["sky_as_depth"]
            assert sky.shape == (2,) and (np.all(np.isnan(sky)) if not r["sky"].any() else
                                          np.all((sky >= 0) & (sky <= 1)))
            at_edge = s["dropped_at_edge"]
            assert at_edge.shape == (2,) and np.all(np.isnan(at_edge) | ((at_edge >= 0) & (at_edge <= 1)))
        assert not (r["sky"] & r["valid"]).any() and 0 <= r["edge_share"] <= 1 and 0 <= r["near_share"] <= 1
        assert real_photons.goal(entry) is not None
    text = real_photons.tables(results, recordings)
    assert "## tower" in text and "## two_layer" in text and "next to the reference's gaps" in text
    goals, _ = real_photons.goal_table(results)
    assert "TR4 - bicubic" in goals
    real_photons.picture(results, recordings, tmp_path / "p.png")
    assert (tmp_path / "p.png").stat().st_size > 0
    json.dumps(real_photons.raw(results, {"TR4": "bundled tr0"}, {}), allow_nan=False)
    assert results["tower"]["sky"].any()  # the crop holds sky: the other side of the decision is measured
    tower = results["tower"]["levels"][0]["scores"]  # and both decisions empty some of what TR4 alone shows of it
    assert all(tower[d]["sky_as_depth"].sum() < tower["TR4"]["sky_as_depth"].sum() for d in ("TR4+test", "TR4+shares"))


def test_a_photon_model_reads_the_depth_and_the_photons_behind_it():
    """model_input gives a depth-only network the centre of mass and a photon network its channels, depth first."""
    import jax

    from jaxsr.config import ModelConfig
    from jaxsr.nn import Model, init_model

    rng = np.random.default_rng(0)
    counts = rng.poisson(0.5, (2, 6, 6, 16)).astype(np.float32)
    counts[..., 7] += rng.poisson(6.0, (2, 6, 6))
    gate, scale = jaxsr.Gate(16, 35.0 / 16, 0.0), jaxsr.DepthScale()
    depth, _ = real_photons._network_depth(counts, gate, scale, 0.0)
    frames = real_photons.PhotonFrames(counts, np.asarray(depth, np.float32), gate, scale)
    cfg = ModelConfig(tr=0, base=8, growth=4, head=16, filter_hidden=16)
    wide = ModelConfig(tr=0, base=8, growth=4, head=16, filter_hidden=16, inputs=("depth", "signal", "background"))
    np.testing.assert_array_equal(real_photons.model_input(Model(*init_model(jax.random.key(0), cfg), cfg), frames),
                                  frames.depth)
    x = real_photons.model_input(Model(*init_model(jax.random.key(0), wide), wide), frames)
    assert x.shape == (2, 6, 6, 3)
    np.testing.assert_allclose(x[..., 0], frames.depth, atol=1e-6)
    np.testing.assert_allclose(x[..., 1:], jaxsr.nn.network_inputs(counts, jaxsr.Sensor(),
                                                                   wide.inputs)[..., 1:], atol=1e-6)


def test_returns_kept_overrules_the_head_only_where_the_block_shows_a_return():
    """--keep-returns: where a block's own photons over 9 frames show a return, the output is the depth under the
    head whatever the head says; elsewhere it is the model's own decision (super_resolve's output); a head that
    marks nothing is left as it is."""
    import jax

    import _photon_benchmark as bench
    from jaxsr.config import ModelConfig
    from jaxsr.nn import Model, init_model

    rng = np.random.default_rng(1)
    counts = rng.poisson(0.05, (3, 6, 6, 16)).astype(np.float32)  # ambient alone: next to no photons
    counts[:, :3, :, 7] += 6.0 + np.arange(3)[:, None, None]  # the top half: a return of 6-8 photons in one bin
    gate, scale = jaxsr.Gate(16, 35.0 / 16, 0.0), jaxsr.DepthScale()
    depth, _ = real_photons._network_depth(counts, gate, scale, 0.0)
    frames = real_photons.PhotonFrames(counts, np.asarray(depth, np.float32), gate, scale)
    cfg = ModelConfig(tr=1, base=8, growth=4, head=16, filter_hidden=16, same_blocks=1,
                      inputs=("depth", "signal", "background"), no_return_head=True)
    params, state = init_model(jax.random.key(0), cfg)
    bias = params["no_return"]["conv2"]["b"]
    quiet = bench.no_return_decision(counts, jaxsr.Sensor(), ("keep", 1e-3))
    assert quiet.shape == (3, 6, 6) and not quiet[:, :3].any() and quiet[:, 3:].all()
    for shift, calls_sky in ((50.0, True), (-50.0, False)):  # a head that calls everything sky, then nothing
        params["no_return"]["conv2"]["b"] = bias + shift
        model = Model(params, state, cfg)
        x = real_photons.model_input(model, frames)
        decided = np.asarray(jaxsr.super_resolve(model, x, form="model"))
        kept = bench.returns_kept(model, x, np.arange(3), quiet)
        assert kept.shape == decided.shape == (3, 24, 24)
        if not calls_sky:
            np.testing.assert_allclose(kept, decided, atol=1e-6)
            continue
        assert np.all(decided == 1.0)
        assert np.all(kept[:, 12:] == 1.0)  # ambient alone: the head's no return stands
        # the return's blocks: the depth under the head, frame by frame (as the head-less decision gives it)
        never = jaxsr.nn.with_no_return_logit(model, 1e9)
        np.testing.assert_allclose(kept[:, :12], np.asarray(jaxsr.super_resolve(never, x, form="model"))[:, :12],
                                   atol=1e-6)


def test_edge_sky_is_the_empty_sky_beside_the_surfaces():
    """edge_sky: pixels outside the block-level sky whose 3 x 3 neighbourhood holds at most REF_EDGE_SKY_PHOTONS
    photons; a surface's pixels, and the sky touching them, are not."""
    photons = np.zeros((12, 12), np.int64)
    photons[:, :5] = 4  # a surface on the left, sky (no photons) on the right
    photons[2, 9] = 1  # one stray ambient photon: its neighbourhood still counts as sky
    photons[8, 9] = 2  # two: not
    sky = np.zeros((12, 12), bool)
    sky[:, 10:] = True  # the block-level reference's sky
    beside = real_photons.edge_sky(photons, sky)
    assert not beside[:, :6].any()  # the surface and the column touching it
    assert not beside[sky].any()  # left to the block-level reference
    expected = np.zeros((12, 12), bool)
    expected[:, 6:10] = True
    expected[7:10, 8:10] = False  # within one pixel of the two photons at (8, 9)
    np.testing.assert_array_equal(beside, expected)


def test_found_sources_first_folder_holding_each_file(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir(), b.mkdir()
    (a / "tower.mat").write_bytes(b"")
    (b / "tower.mat").write_bytes(b"")
    (b / "face.mat").write_bytes(b"")
    found = {s.name: f for s, f in real_photons.found_sources([a, b])}
    assert found["tower"] == a and found["face"] == b  # the first folder that holds it
    assert found["two_layer"] is None  # held by none: skipped by main


@pytest.mark.slow  # a compile of tr4-ambient and of the library's job: 20-80 s on 2 cores
def test_the_studys_default_decision_is_jaxsr_upscale_where_their_depth_spans_agree():
    """`confidence_decided` + `with_ensemble` + `with_holes_filled` re-make `jaxsr.upscale`'s default decision on
    the study's frames; where the span the study reads equals the one `jaxsr.upscale` fits (a 16-bin gate of 35 m
    from 0), `upscaled` (the library itself) gives the same depth. A black patch amid the returns: its fill too."""
    rng = np.random.default_rng(4)
    gate = jaxsr.Gate.spanning(35.0, 16)
    rates = np.full((9, 8, 12, 16), 0.5 / 16)
    rates[:, :, :7, 5] += 4.0  # a surface at bin 5 ...
    rates[:, 3:5, 2:4] = 0.0  # ... with a black patch that it encloses
    counts = rng.poisson(rates).astype(np.float32)
    scale = jaxsr.DepthScale.for_gate(gate)
    frames = real_photons.PhotonFrames(counts, np.zeros(counts.shape[:3], np.float32), gate, scale)
    levels = jaxsr.app.photon_levels(iter(counts), 16)
    model = jaxsr.load_model("tr4-ambient")
    study = real_photons.with_holes_filled(real_photons.with_ensemble(
        real_photons.confidence_decided(model, frames, 1e-3), frames, levels), frames, 1e-3)
    assert jaxsr.sensor.black_hole_pixels(counts, alpha=1e-3)[:, 3:5, 2:4].all()
    np.testing.assert_allclose(np.clip(real_photons.upscaled(frames), 0, 1), np.clip(study, 0, 1), atol=1e-5)
