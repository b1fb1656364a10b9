"""Networks that read the photons behind each depth and mark no return (ModelConfig.inputs, no_return_head):
the evidence and its encoding, widening a depth-only model without changing its function, the no-return head's
output and loss, the inference paths (windows, sequence, stream, tiles, histograms) and the file round trip."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsr.config import ModelConfig, PhotonRegime, Sensor, TrainConfig
from jaxsr.inference import Stream, super_resolve, super_resolve_histograms
from jaxsr.io.checkpoint import load_model, save_model
from jaxsr.nn import (Model, apply_model, apply_model_features, apply_model_raw, apply_model_train, encode_photons,
                      flops_per_frame, init_model, merge_no_return, network_inputs, no_return_logits,
                      with_photon_inputs)
from jaxsr.sensor import ambient_photons, centre_of_mass, peak_evidence
from jaxsr.temporal import windows as temporal_windows
from jaxsr.training import regime_batches, regime_parameters
from jaxsr.training.duf import initial_weights, model_loss

SENSOR = Sensor()
TINY = dict(base=8, growth=4, head=16, filter_hidden=16)
PHOTONS = ("depth", "signal", "background")
# the network compiled whole: eagerly each of its ops compiles on its own (seconds per test)
_apply = jax.jit(apply_model, static_argnames="cfg")
_inputs = jax.jit(network_inputs, static_argnames="inputs")
AMBIENT = (*PHOTONS, "ambient")


def _histogram(signal_bin=None, signal=0.0, background=0.0):
    n = np.full(SENSOR.bins, background / SENSOR.bins, np.float32)
    if signal_bin is not None:
        n[signal_bin] += signal
    return n


def test_peak_evidence_counts_the_return_and_the_ambient_photons():
    counts = np.stack([_histogram(5, 30.0, 16.0), _histogram(None, 0.0, 16.0), np.zeros(16, np.float32)])
    signal, background = peak_evidence(counts, SENSOR)
    np.testing.assert_allclose(signal, [30.0, 0.0, 0.0], atol=1e-5)
    np.testing.assert_allclose(background, [16.0, 16.0, 0.0], atol=1e-5)
    with pytest.raises(ValueError, match="peak_evidence"):
        peak_evidence(-counts[:1], SENSOR)


def test_peak_evidence_tells_ambient_light_from_a_mid_gate_surface():
    """The centre of mass of ambient photons alone reads as a surface; the signal does not."""
    key = jax.random.key(0)
    ambient = jax.random.poisson(key, 2.0, (4096, 16)).astype(jnp.float32)  # 32 ambient photons, no return
    surface = ambient.at[:, 8].add(jax.random.poisson(jax.random.fold_in(key, 1), 30.0, (4096,)))
    depth, valid = centre_of_mass(ambient, SENSOR, return_mask=True)
    assert float(jnp.mean(valid)) > 0.9  # the centre of mass calls most of them a return
    s_amb, _ = peak_evidence(ambient, SENSOR)
    s_sur, _ = peak_evidence(surface, SENSOR)
    assert float(jnp.quantile(s_amb, 0.99)) < float(jnp.quantile(s_sur, 0.01))


def test_ambient_photons_from_the_bins_outside_the_peak():
    flat = _histogram(None, 0.0, 16.0)
    sparse = np.zeros(16, np.float32)
    sparse[[1, 13]], sparse[8] = 1.0, 3.0  # 3 signal photons, 2 ambient ones: the median bin is 0
    counts = np.stack([_histogram(5, 30.0, 16.0), flat, sparse, np.zeros(16, np.float32)])
    # the window is the peak +- 1 bin at the default pulse: 13 bins outside
    np.testing.assert_allclose(ambient_photons(counts, SENSOR), [16.0, 16.0, 2.0 * 16 / 13, 0.0], rtol=1e-5)
    assert float(peak_evidence(sparse, SENSOR)[1]) == 0.0  # what the median-based background reads there
    np.testing.assert_allclose(ambient_photons(counts[:1], SENSOR, window=0), [16.0], rtol=1e-5)
    assert float(ambient_photons(flat, SENSOR, window=16)) == 0.0  # the window covers the gate: no estimate
    huge = np.asarray(ambient_photons(np.full((1, 16), 3e38, np.float32), SENSOR))
    assert np.all(np.isfinite(huge)) and huge[0] > 1e38
    with pytest.raises(ValueError, match="ambient_photons"):
        ambient_photons(-counts[:1], SENSOR)


@pytest.mark.parametrize("ambient_per_bin", [0.05, 0.5, 5.0])
def test_ambient_photons_reads_the_level_beside_a_return_where_the_median_reads_nothing(ambient_per_bin):
    """At 3 signal photons the median-based background is 0 in most pixels at low ambient light; beside the
    return, the mean outside the peak estimates the ambient photons within 10 % at every level."""
    key = jax.random.key(3)
    n = jax.random.poisson(key, ambient_per_bin, (20000, 16)).astype(jnp.float32)
    n = n.at[:, 9].add(jax.random.poisson(jax.random.fold_in(key, 1), 3.0, (20000,)))
    estimate = np.asarray(ambient_photons(n, SENSOR))
    # the argmax sits on the ambient photons' own maximum now and then, which biases the estimate low by a little
    assert abs(estimate.mean() / (16 * ambient_per_bin) - 1) < 0.1
    if ambient_per_bin < 1:
        assert float(jnp.mean(peak_evidence(n, SENSOR)[1] == 0)) > 0.5  # 100 % at 0.05, 64 % at 0.5


def test_encoding_and_inputs():
    assert float(encode_photons(0.0)) == 0.0 and abs(float(encode_photons(1000.0)) - 1.0) < 1e-6
    assert np.all(np.isfinite(np.asarray(encode_photons(jnp.asarray([0.0, 1e30, 3e38])))))
    counts = jnp.asarray(np.stack([_histogram(5, 30.0, 16.0), _histogram(None, 0.0, 0.0)]))
    x = network_inputs(counts, SENSOR, PHOTONS)
    assert x.shape == (2, 3)
    np.testing.assert_allclose(x[:, 0], centre_of_mass(counts, SENSOR))
    np.testing.assert_allclose(x[0, 1:], encode_photons(jnp.asarray([30.0, 16.0])), rtol=1e-5)
    np.testing.assert_array_equal(network_inputs(counts, SENSOR), centre_of_mass(counts, SENSOR))
    np.testing.assert_allclose(network_inputs(counts, SENSOR, ("depth", "background"))[0, 1], x[0, 2])
    xa = network_inputs(counts, SENSOR, AMBIENT)
    np.testing.assert_array_equal(xa[..., :3], x)
    np.testing.assert_allclose(xa[:, 3], encode_photons(ambient_photons(counts, SENSOR)))
    for bad in ((), ("signal",), ("depth", "colour")):
        with pytest.raises(ValueError, match="inputs"):
            network_inputs(counts, SENSOR, bad)


def test_inputs_have_finite_gradients_at_zero_and_huge_counts():
    counts = jnp.asarray(np.stack([np.zeros(16, np.float32), _histogram(3, 3e30, 1e30)]))
    grad = jax.grad(lambda c: jnp.sum(network_inputs(c, SENSOR, AMBIENT)))(counts)
    assert np.all(np.isfinite(np.asarray(grad)))


def test_config_checks_inputs():
    assert ModelConfig(inputs=["depth", "signal"]).inputs == ("depth", "signal")  # a list from JSON
    assert ModelConfig(inputs=PHOTONS).channels == 3
    for bad in (("signal", "depth"), ("depth", "depth"), ("depth", "light"), (), "depth"):
        with pytest.raises(ValueError, match="inputs"):
            ModelConfig(inputs=bad)
    with pytest.raises(ValueError, match="no_return_head"):
        ModelConfig(no_return_head=1)


def _tiny_depth_model(tr=1, seed=0):
    cfg = ModelConfig(tr=tr, **TINY)
    params, state = jax.jit(init_model, static_argnames="cfg")(jax.random.key(seed), cfg)
    # BN statistics away from their initial values, so that the comparison below is not trivial (NumPy draws: a
    # JAX one per leaf shape compiles a kernel each)
    rng = np.random.default_rng(seed + 1)
    state = jax.tree_util.tree_map(lambda v: v + 0.1 * rng.uniform(size=v.shape).astype(np.float32), state)
    return Model(params, state, cfg)


def _photon_frames(t=5, h=8, w=10, seed=2):
    counts = jax.random.poisson(jax.random.key(seed), 1.5, (t, h, w, SENSOR.bins)).astype(jnp.float32)
    return counts, np.asarray(_inputs(counts, SENSOR, PHOTONS))


def test_widened_model_computes_the_depth_only_function():
    model = _tiny_depth_model()
    wide = with_photon_inputs(jax.random.key(5), model)
    assert wide.config.inputs == PHOTONS and wide.config.no_return_head
    _, x = _photon_frames()
    win = temporal_windows(x, 1)
    np.testing.assert_allclose(_apply(wide.params, wide.state, win, wide.config),
                               _apply(model.params, model.state, win[..., 0], model.config), rtol=1e-6, atol=1e-6)
    with pytest.raises(ValueError, match="widen"):  # nothing to add
        with_photon_inputs(jax.random.key(5), wide)
    with pytest.raises(ValueError, match="widen"):  # an input dropped
        with_photon_inputs(jax.random.key(5), wide, ("depth", "ambient"))
    with pytest.raises(ValueError, match="widen"):  # the head dropped
        with_photon_inputs(jax.random.key(5), wide, AMBIENT, no_return_head=False)
    with pytest.raises(ValueError, match="inputs"):  # depth alone to a photon network
        apply_model(wide.params, wide.state, win[..., 0], wide.config)
    assert flops_per_frame(wide.config) > flops_per_frame(model.config)


def test_no_return_head_marks_pixels_and_its_loss_learns_them():
    cfg = ModelConfig(tr=0, inputs=PHOTONS, no_return_head=True, **TINY)
    params, state = jax.jit(init_model, static_argnames="cfg")(jax.random.key(0), cfg)
    _, x = _photon_frames(t=2)
    out, _ = jax.jit(apply_model_train, static_argnames="cfg")(params, state, x[:, None], cfg)
    assert out.shape == (2, 32, 40, 2)
    np.testing.assert_array_equal(out[..., 1], -4.0)  # a new head says "return" everywhere
    merged = merge_no_return(out.at[0, :4, :, 1].set(3.0), cfg)
    assert np.all(np.asarray(merged[0, :4]) == 1.0) and np.array_equal(merged[0, 4:], out[0, 4:, :, 0])
    gt = jnp.full(out.shape[:-1], 0.5).at[:, :16].set(1.0)
    train_cfg = TrainConfig()

    def loss(logit_bias):
        return model_loss(out.at[..., 1].add(logit_bias), gt, cfg, train_cfg)
    # half the pixels have no return: the cross-entropy is lowest for logits near 0 from -4
    assert float(loss(4.0)) < float(loss(0.0)) and np.isfinite(float(loss(1e4)))
    assert float(jax.grad(loss)(0.0)) < 0
    # the depth of a pixel without a return is the head's business: it does not move the loss
    moved = out.at[:, :16, :, 0].add(0.3)
    assert float(model_loss(moved, gt, cfg, train_cfg)) == float(model_loss(out, gt, cfg, train_cfg))
    assert float(model_loss(out.at[:, 16:, :, 0].add(0.3), gt, cfg, train_cfg)) > float(loss(0.0))


def test_the_head_features_and_the_no_return_branch_give_the_networks_logit():
    """apply_model_features + no_return_logits: the logit apply_model_raw outputs, from features computed once."""
    model = with_photon_inputs(jax.random.key(1), _tiny_depth_model(tr=1))
    branch = model.params["no_return"]  # changed in place: the network's own branch, which apply_model_raw runs
    branch["conv2"] = {"w": jax.random.normal(jax.random.key(4), branch["conv2"]["w"].shape),
                       "b": branch["conv2"]["b"] + 4.0}
    _, x = _photon_frames(t=3, h=6, w=9)
    windows = temporal_windows(x, 1)
    raw = apply_model_raw(model.params, model.state, windows, model.config)
    features = apply_model_features(model.params, model.state, windows, model.config)
    assert features.shape == (3, 6, 9, model.config.head)
    logit = no_return_logits(branch, features[:, None], model.config)[:, 0]
    assert float(jnp.std(logit)) > 0.1  # a branch that varies, not its constant start
    np.testing.assert_allclose(logit, raw[..., 1], atol=1e-5)
    with pytest.raises(ValueError, match="apply_model_features"):
        apply_model_features(model.params, model.state, windows[..., 0], model.config)


@pytest.mark.slow  # every inference path compiled (15 s)
def test_photon_model_runs_the_same_through_every_inference_path():
    model = with_photon_inputs(jax.random.key(1), _tiny_depth_model())
    head = model.params["no_return"]["conv2"]
    model.params["no_return"]["conv2"] = {"w": 0.3 * jax.random.normal(jax.random.key(4), head["w"].shape),
                                          "b": head["b"] + 4.0}
    counts, x = _photon_frames(t=5, h=8, w=30)
    want = np.asarray(_apply(model.params, model.state, temporal_windows(x, 1), model.config))
    assert 0.05 < np.mean(want == 1.0) < 0.95  # the head marks some pixels
    np.testing.assert_allclose(super_resolve(model, x), want, atol=1e-5)
    np.testing.assert_allclose(super_resolve(model, x, tile=16), want, atol=1e-5)
    np.testing.assert_allclose(super_resolve_histograms(model, np.asarray(counts)), want, atol=1e-5)
    seq = Model(model.params, model.state, dataclasses.replace(model.config, temporal="sequence"))
    stream = Stream(seq)
    outs = [o for o in (stream.push(f) for f in x) if o is not None] + stream.flush()
    np.testing.assert_allclose(np.stack(outs), super_resolve(seq, x), atol=1e-5)
    with pytest.raises(ValueError, match="super_resolve_histograms"):
        super_resolve(model, x[..., 0])
    bad = x.copy()
    bad[0, 0, 0, 1] = -1.0
    with pytest.raises(ValueError, match="finite and >= 0"):
        super_resolve(model, bad)


def test_photon_model_file_round_trip(tmp_path):
    model = with_photon_inputs(jax.random.key(1), _tiny_depth_model())
    loaded = load_model(save_model(tmp_path / "m.npz", model))
    assert loaded.config == model.config
    _, x = _photon_frames(t=3)
    np.testing.assert_array_equal(super_resolve(loaded, x), super_resolve(model, x))


def test_initial_weights_widen_a_depth_only_init():
    model = _tiny_depth_model()
    cfg = dataclasses.replace(model.config, inputs=PHOTONS, no_return_head=True)
    params, state = initial_weights(jax.random.key(0), cfg, model)
    assert params["stem"]["w"].shape[-2] == 3 and "no_return" in params
    np.testing.assert_array_equal(params["stem"]["w"][..., 1:, :], 0.0)


def test_a_photon_model_widened_to_the_ambient_channel_computes_its_function():
    """The ambient model starts from a trained photon model: its head kept, the new channel's kernels zero, the
    others carried by name (also when the order of the inputs differs)."""
    photon = with_photon_inputs(jax.random.key(1), _tiny_depth_model())
    photon = Model({**photon.params, "stem": {**photon.params["stem"],
                                              "w": photon.params["stem"]["w"] + 0.01}}, photon.state, photon.config)
    counts, x = _photon_frames()
    xa = np.asarray(network_inputs(counts, SENSOR, AMBIENT))
    for order in (AMBIENT, ("depth", "ambient", "signal", "background")):
        cfg = dataclasses.replace(photon.config, inputs=order)
        params, state = initial_weights(jax.random.key(0), cfg, photon)
        jax.tree_util.tree_map(np.testing.assert_array_equal, params["no_return"], photon.params["no_return"])
        win = temporal_windows(xa[..., [AMBIENT.index(name) for name in order]], 1)
        np.testing.assert_allclose(_apply(params, state, win, cfg),
                                   _apply(photon.params, photon.state, temporal_windows(x, 1), photon.config),
                                   rtol=1e-6, atol=1e-6)
    with pytest.raises(ValueError, match="architecture"):  # a channel dropped is not a widening
        initial_weights(jax.random.key(0), dataclasses.replace(photon.config, inputs=("depth", "signal")), photon)


@pytest.mark.slow  # compiles the regime's rendering and sensor (about 2 min on 2 busy cores)
def test_regime_batches_give_photon_channels():
    train_cfg = TrainConfig(batch_size=2, patch=(8, 8))
    windows, gt = jax.jit(regime_batches(1, train_cfg, PhotonRegime(), sensor=SENSOR, inputs=PHOTONS))(
        jax.random.key(3))
    assert windows.shape == (2, 3, 8, 8, 3) and gt.shape == (2, 32, 32)
    assert np.all(np.isfinite(np.asarray(windows))) and float(windows[..., 1:].min()) >= 0


def test_regime_paper_share():
    draws = jax.vmap(lambda k: regime_parameters(k, PhotonRegime(paper_prob=0.5)))(
        jax.random.split(jax.random.key(0), 400))
    paper = np.asarray(draws["irf_sigma"] == 0.4) & np.asarray(draws["dark"] == 0) & np.asarray(
        draws["mean_signal"] >= 7) & np.asarray(draws["mean_signal"] <= 28)
    assert 0.4 < paper.mean() < 0.7
    # paper_prob 0 leaves the wide regime's draws as they were
    key = jax.random.key(9)
    a, b = regime_parameters(key, PhotonRegime()), regime_parameters(key, PhotonRegime(paper_prob=0.0))
    assert all(float(a[k]) == float(b[k]) for k in a)
