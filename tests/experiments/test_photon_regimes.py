"""The photon benchmark (experiments/studies/_photon_benchmark.py) and its report (photon_regimes.py) on a tiny
configuration: a synthetic 12-frame sequence, one photon level and SNR, 2 frames, a small random network; the
no-return measure on constructed outputs."""

from types import SimpleNamespace

import jax
import numpy as np
import pytest

import _photon_benchmark as bench  # experiments/studies (pytest's pythonpath)
import photon_regimes
from jaxsr.config import ModelConfig, Sensor
from jaxsr.nn import Model, init_model

TINY = dict(base=8, growth=4, head=16, filter_hidden=16)


def synthetic_sequence(frames=12, snr=1.3):
    """A sloped floor with a box moving across it (radial metres), uniform reflectivity."""
    h, w = Sensor().hr_shape
    depth = np.broadcast_to(np.linspace(30.0, 5.0, h, dtype=np.float32)[:, None], (frames, h, w)).copy()
    for t in range(frames):
        depth[t, 40:80, 20 + 4 * t:60 + 4 * t] = 8.0
    intensity = np.full_like(depth, 0.6)
    return SimpleNamespace(name="synthetic", depth=depth, intensity=intensity, fps=30.0, snr=snr)


@pytest.fixture(scope="module")
def results():
    cfg = ModelConfig(tr=1, **TINY)
    tiny = Model(*init_model(jax.random.key(0), cfg), cfg)
    # labelled TR4 so that the "today" goal (against the bundled TR4) has its reference
    return bench.evaluate({"TR4": tiny}, {"synthetic": synthetic_sequence()}, frames=2, photons=[3.0],
                                   snrs=[1.3], log=lambda _: None)


def test_regimes_methods_and_finite_scores(results):
    assert [(r["photons"], r["snr"]) for r in results["regimes"]] == [(3.0, 1.3), (14.0, None)]  # + the paper's
    assert results["methods"] == ["bicubic", "TR4"]
    for r in results["regimes"]:
        for m in results["methods"]:
            for metric in ("psnr", "ssim"):
                scores = r["scores"][m][metric]
                assert scores.shape == (1, 2) and np.all(np.isfinite(scores))
    assert [e["photons"] for e in results["no_return"]] == [3.0]
    entry = results["no_return"][0]
    for rates in (entry["rates"], entry["interior"]):
        assert set(rates) == {"bicubic", "TR4", bench.MAJORITY}
        assert all(0 <= v <= 100 for pair in rates.values() for v in pair)
    assert 0 < entry["interior_share"] < 1


def test_tables_and_json(results):
    text = photon_regimes.tables(results)
    psnr_table = text.split("### Mean PSNR")[1].split("###")[0]
    rows = [line for line in psnr_table.splitlines() if line.startswith("| ") and "photons" not in line]
    assert [row.split("|")[1:3] for row in rows] == [[" 3 ", " 1.3 "], [" 14 ", " own "]]
    assert "| 3 | 1.3 |" in text.split("### No return")[1] and "| 3 | 1.3 |" in text.split("inside the regions")[1]
    assert "nan" not in text.lower()
    goals = photon_regimes.goals(results)["TR4"]
    assert goals["today"]["value"] == pytest.approx(0.0)  # TR4 against itself
    assert goals["100"]["met"] is None and goals["tv"]["met"] is None  # not in this grid
    assert goals["low"]["value"] is not None and goals["as_depth"]["value"] is not None
    raw = photon_regimes.raw(results, {"TR4": "random tiny"})
    assert raw["regimes"][1]["snr"] == "own" and len(raw["regimes"][0]["scores"]["TR4"]["psnr"][0]) == 2
    import json
    json.dumps(raw, allow_nan=False)


def test_no_return_measure_on_constructed_outputs():
    gt = np.array([[1.0, 1.0, 0.5, 0.2], [1.0, 0.9, 0.3, 0.995]])  # 3 without a return, 5 returns
    # everything read as no return: every return dropped, no no-return pixel output as depth
    assert bench.no_return_rates(np.ones_like(gt), gt) == (0.0, 100.0)
    # everything a near return: every no-return pixel output as depth, none dropped
    assert bench.no_return_rates(np.full_like(gt, 0.1), gt) == (100.0, 0.0)
    # one no-return pixel as depth (1 of 3), one return dropped (NaN, 1 of 5)
    sr = np.array([[0.5, 1.2, 0.5, np.nan], [1.0, 0.9, 0.3, 0.5]])
    as_depth, dropped = bench.no_return_rates(sr, gt)
    assert as_depth == pytest.approx(100 / 3) and dropped == pytest.approx(20.0)


def test_no_return_regions_reach_the_ground_truth():
    seq = synthetic_sequence(frames=2)
    dark = bench.with_no_return({"s": seq})["s"]
    sky = ~np.isfinite(dark.depth)
    assert np.all(sky[0] == sky[1])  # one mask for the whole sequence
    assert sky[0].mean() == pytest.approx(bench.NO_RETURN_FRACTION, abs=0.01)
    clips, flags = bench.benchmark_clips({"s": dark}, 100.0, 1.3, scored=np.array([1]), radius=1,
                                               key=jax.random.key(0), tests=(("flags", 1e-3), ("shares", 1e-3)))
    assert np.array_equal(clips["s"].gt[0] >= 1.0, sky[0])
    # the ambient-only test of the scored frame: most of the sky's LR blocks, almost none of the returns'
    (flag,) = flags["s"][("flags", 1e-3)]
    blocks = sky[1].reshape(flag.shape[0], 4, flag.shape[1], 4).mean(axis=(1, 3))
    assert flag[blocks == 1.0].mean() > 0.5 and flag[blocks == 0.0].mean() < 0.01
    # the shares grow from the flags: more of the sky, still almost none of the returns
    (share,) = flags["s"][("shares", 1e-3)]
    assert (share[flag] == 1.0).all() and (share[blocks == 1.0] == 1.0).mean() > flag[blocks == 1.0].mean()
    assert (share[blocks == 0.0] >= 0.5).mean() < 0.01


def test_frames_far_apart_are_resampled_one_by_one():
    a, b = np.array([[1.0, 3.0, 2.0, 6.0]]), np.zeros((1, 4))
    iv = bench.frame_interval(a, b, spacing=125.0)  # 4 frames spread over 500: blocks of 1
    assert float(iv.mean) == pytest.approx(3.0) and float(iv.low) < 3.0 < float(iv.high)
    near = bench.frame_interval(a, b, spacing=1.0)  # consecutive frames: one block of all 4
    assert float(near.low) == pytest.approx(3.0) == pytest.approx(float(near.high))


def test_interior_and_the_block_majority():
    """interior: the pixel's 4 x 4 block and its 8 neighbours of one kind (either kind, so the insides of both);
    block_majority: each block decided by at least half of its pixels (a tie is no return)."""
    big = np.zeros((32, 32), bool)
    big[4:28, 4:28] = True  # blocks 1-6 of 0-7 are all sky, blocks 0 and 7 all returns
    inside = bench.interior(big, 4)
    blocks = inside[::4, ::4]
    assert np.all(inside == np.kron(blocks, np.ones((4, 4), bool)))
    assert blocks[2:6, 2:6].all() and not blocks[1, 1:7].any() and not blocks[1:7, 1].any()  # sky: 2-5 inside
    assert not blocks[0, :].any()  # a return block beside sky blocks is on the edge
    assert bench.interior(np.zeros((16, 16), bool), 4).all()  # one kind everywhere: all inside
    sky = np.zeros((16, 16), bool)
    sky[2:10, 4:14] = True
    majority = bench.block_majority(sky, 4)
    b = majority[::4, ::4]
    assert np.all(majority == np.kron(b, np.ones((4, 4), bool)))
    assert b[0, 1] and b[1, 1] and b[2, 1] and b[1, 3]  # half or more of the block
    assert not b[0, 0] and not b[0, 3] and not b[2, 3] and not b[3, 1]  # a quarter or none


def test_load_models_gives_each_name_one_no_return_decision():
    """--ambient-alpha gives a rate (the test's flags), --no-return-shares ("shares", rate), real_photons'
    --keep-returns ("keep", rate), which only a model with a no-return head takes; an unknown kind is refused;
    one name in two of them is refused, as is a rate out of (0, 1)."""
    _, _, ambient = bench.load_models(["A=tr4", "B=tr4", "C=tr4-photons"], (), ["A=0.001"], ["B=0.01"],
                                               ["C=0.001"])
    assert ambient == {"A": 0.001, "B": ("shares", 0.01), "C": ("keep", 0.001)}
    assert [bench.decision_of(v) for v in ambient.values()] == [("flags", 0.001), ("shares", 0.01),
                                                                         ("keep", 0.001)]
    with pytest.raises(SystemExit, match="one decision per model name"):
        bench.load_models(["A=tr4"], (), ["A=0.001"], ["A=0.001"])
    with pytest.raises(SystemExit, match="one decision per model name"):
        bench.load_models(["A=tr4-photons"], (), ["A=0.001"], (), ["A=0.001"])
    with pytest.raises(SystemExit, match="no no-return head"):
        bench.load_models(["A=tr4"], (), (), (), ["A=0.001"])
    with pytest.raises(ValueError, match="unknown decision 'sky'"):
        bench.no_return_decision(np.zeros((1, 2, 2, 16), np.float32), Sensor(), ("sky", 1e-3))
    with pytest.raises(SystemExit, match=r"false-alarm rate in \(0, 1\)"):
        bench.load_models(["A=tr4"], (), (), ["A=2"])


@pytest.mark.slow  # a second `evaluate` (18 s on 2 cores); `returns_kept` itself: test_real_photons
def test_keep_returns_gives_back_the_returns_a_head_drops():
    """--keep-returns through `evaluate`: a head that calls every pixel sky drops every return of the no-return
    test; kept where each pixel's own photons over 9 frames show a return, more than half come back (3 photons,
    SNR 1.3: here 63 % of single pixels over 9 frames stand out at alpha 0.001)."""
    cfg = ModelConfig(tr=1, inputs=("depth", "signal", "background"), no_return_head=True, **TINY)
    params, state = init_model(jax.random.key(0), cfg)
    params["no_return"]["conv2"]["b"] = params["no_return"]["conv2"]["b"] + 50.0
    sky = Model(params, state, cfg)
    results = bench.evaluate({"P": sky, "P+keep": sky}, {"synthetic": synthetic_sequence()}, frames=1,
                                      photons=[3.0], snrs=[1.3], paper=False, ambient={"P+keep": ("keep", 1e-3)},
                                      log=lambda _: None)
    (entry,) = results["no_return"]
    as_depth, dropped = entry["rates"]["P"]
    kept_as_depth, kept_dropped = entry["rates"]["P+keep"]
    assert as_depth == 0.0 and dropped == 100.0
    assert kept_dropped < dropped / 2 and kept_as_depth < 100.0


def test_static_scenes_show_the_nearest_scored_frame():
    """--static: every frame shows the scored frame nearest to it (a tie goes to the earlier); evaluate refuses
    scored frames whose windows would hold two of them."""
    shown = bench.nearest_scored(20, [5, 15])
    np.testing.assert_array_equal(shown, np.where(np.arange(20) <= 10, 5, 15))
    with pytest.raises(ValueError, match="too close"):
        bench.evaluate({}, {"s": synthetic_sequence(frames=12)}, frames=4, photons=[14.0], snrs=[1.3],
                                no_return=False, ambient={"x": 1e-3}, static=True, log=lambda _: None)
