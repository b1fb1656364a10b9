"""HistNet, iSeeBetter (RBPN + SRGAN discriminator) and the Lucas-Kanade flow.

Parameter counts are checked against layer lists written out here from the published code (HWQuantum/HistNet
`model_network_hist.py`; alterzero/RBPN-PyTorch and amanchadha/iSeeBetter `rbpn.py`, `dbpns.py`,
`base_networks.py`, `SRGAN/model.py`), independently of the modules' own construction. Full-size networks are only
traced (`jax.eval_shape`); the training tests use reduced widths."""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxsr
from jaxsr.config import Optics, Sensor
from jaxsr.nn import count_params


def conv(k, cin, cout):
    """Weights + biases of a k x k (transposed) convolution."""
    return k * k * cin * cout + cout


# --- parameter counts ------------------------------------------------------------------------------------------

# HistNet as the published code builds it (width 64): (k, cin, cout) of every conv and transposed conv. The code
# declares 1024 -> 512 (intensity conv2d_7) and 3072 -> 512 (conv2d_13), but its conv2d reads the input width from
# the tensor: 256 and 512 + 512 + 512 = 1536.
HISTNET_PUBLISHED = [
    (3, 1, 64), (3, 64, 128), (3, 128, 256), (3, 256, 512),  # intensity branch
    (3, 2, 64), (3, 64, 64), (3, 1, 64), (3, 128, 128), (3, 128, 128), (3, 1, 128), (3, 256, 256), (3, 256, 256),
    (3, 1, 256), (3, 512, 512), (3, 512, 512), (3, 1, 512), (3, 1024, 1024), (3, 1024, 1024),  # encoder
    (3, 1024, 512), (3, 1536, 512), (3, 512, 512), (3, 512, 256), (3, 768, 256), (3, 256, 256),
    (3, 256, 128), (3, 384, 128), (3, 128, 128), (3, 128, 64), (3, 192, 64), (3, 64, 64), (3, 64, 1),  # decoder
]


def histnet_published(width=64):
    """The published list with every hidden width scaled by width / 64 (inputs of 1 or 2 channels and the 1-channel
    output kept)."""
    s = lambda c: c if c <= 2 else c * width // 64
    return sum(conv(k, s(a), s(b)) for k, a, b in HISTNET_PUBLISHED)


@pytest.mark.parametrize("width", [64, 16])
def test_histnet_parameter_count_matches_the_published_layers(width):
    params = jax.eval_shape(
        lambda k: jaxsr.baselines.init_histnet(k, jaxsr.baselines.HistNetConfig(width=width)), jax.random.PRNGKey(0)
    )
    assert count_params(params) == histnet_published(width)
    if width == 64:
        assert count_params(params) == 45_473_025


def rbpn_published(channels=3, base=256, feat=64, n_res=5, frames=7, k=8):
    """RBPN (iSeeBetter's settings) from RBPN-PyTorch's modules, PReLU slopes (one each) included."""
    prelu_conv = lambda kk, a, b: conv(kk, a, b) + 1
    resblocks = lambda c: n_res * (2 * conv(3, c, c) + 1)  # one PReLU per ResnetBlock
    dbpn = prelu_conv(1, base, feat) + 5 * 3 * prelu_conv(k, feat, feat) + conv(1, 3 * feat, feat)
    return (prelu_conv(3, channels, base) + prelu_conv(3, 2 * channels + 2, base) + dbpn
            + resblocks(base) + prelu_conv(k, base, feat)
            + resblocks(feat) + prelu_conv(3, feat, feat)
            + resblocks(feat) + prelu_conv(k, feat, base)
            + conv(3, (frames - 1) * feat, channels))


def srgan_discriminator_published(channels=3):
    widths = [64, 64, 128, 128, 256, 256, 512, 512]
    total, cin = 0, channels
    for i, c in enumerate(widths):
        total += conv(3, cin, c) + (2 * c if i else 0)  # BN scale and shift after all but the first conv
        cin = c
    return total + conv(1, 512, 1024) + conv(1, 1024, 1)


@pytest.mark.parametrize("channels", [3, 1])
def test_rbpn_and_discriminator_parameter_counts_match_the_published_layers(channels):
    cfg = jaxsr.baselines.RBPNConfig(channels=channels)
    g = jax.eval_shape(lambda k: jaxsr.baselines.init_rbpn(k, cfg), jax.random.PRNGKey(0))
    d = jax.eval_shape(lambda k: jaxsr.baselines.init_discriminator(k, cfg)[0], jax.random.PRNGKey(0))
    assert count_params(g) == rbpn_published(channels)
    assert count_params(d) == srgan_discriminator_published(channels)
    if channels == 3:  # the published code's count (Haris et al. quote 12.2 M for RBPN)
        assert count_params(g) == 12_771_943 and count_params(d) == 5_215_425


# --- shapes at our data's sizes (traced, full published widths) -------------------------------------------------


def test_histnet_shapes():
    cfg = jaxsr.baselines.HistNetConfig()
    params = jax.eval_shape(lambda k: jaxsr.baselines.init_histnet(k, cfg), jax.random.PRNGKey(0))
    counts = jax.ShapeDtypeStruct((2, 32, 64, 16), jnp.float32)
    intensity = jax.ShapeDtypeStruct((2, 128, 256), jnp.float32)
    feats = jax.eval_shape(lambda c: jaxsr.baselines.histnet_features(c, cfg), counts)
    assert {k: v.shape for k, v in feats.items()} == {
        "d1": (2, 128, 256), "d2": (2, 128, 256), "pool1": (2, 64, 128), "pool2": (2, 32, 64),
        "pool3": (2, 16, 32), "pool4": (2, 8, 16)}
    out = jax.eval_shape(lambda p, c, i: jaxsr.baselines.apply_histnet(p, c, i, cfg), params, counts, intensity)
    assert out.shape == (2, 128, 256)
    with pytest.raises(ValueError, match="divisible by 4"):
        jaxsr.baselines.histnet_features(jnp.zeros((1, 30, 64, 16)), cfg)


def test_rbpn_and_discriminator_shapes():
    cfg = jaxsr.baselines.RBPNConfig()
    g = jax.eval_shape(lambda k: jaxsr.baselines.init_rbpn(k, cfg), jax.random.PRNGKey(0))
    dp, ds = jax.eval_shape(lambda k: jaxsr.baselines.init_discriminator(k, cfg), jax.random.PRNGKey(0))
    windows = jax.ShapeDtypeStruct((2, 7, 32, 64), jnp.float32)
    assert jax.eval_shape(lambda w: jaxsr.baselines.rbpn_flows(w, cfg), windows).shape == (2, 6, 32, 64, 2)
    hr = jax.eval_shape(lambda p, w: jaxsr.baselines.apply_rbpn(p, w, cfg), g, windows)
    assert hr.shape == (2, 128, 256)
    logits, _ = jax.eval_shape(
        lambda p, s, x: jaxsr.baselines.apply_discriminator(p, s, x, cfg, train=True), dp, ds, hr
    )
    assert logits.shape == (2,)
    with pytest.raises(ValueError, match="expected windows"):
        jaxsr.baselines.apply_rbpn(g, jnp.zeros((2, 5, 32, 64)), cfg)


# --- the flow estimator -----------------------------------------------------------------------------------------


def texture(shift, h=32, w=64, seed=1):
    """A smooth random texture (12 plane waves, periods >= 12 px) translated by shift = (u, v) pixels: frame(y, x)
    = f(y - v, x - u), so frame(y + v, x + u) = f(y, x)."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w].astype(float)
    out = np.zeros((h, w))
    for _ in range(12):
        fy, fx = rng.uniform(-0.35, 0.35, 2)
        out += np.cos(fy * (y - shift[1]) + fx * (x - shift[0]) + rng.uniform(0, 2 * np.pi))
    return out


def test_flow_recovers_a_known_shift_to_a_tenth_of_a_pixel():
    shifts = [(1.3, -0.7), (3.4, 2.2), (0.0, 0.0)]
    centre = np.stack([texture((0, 0))] * len(shifts))
    neighbour = np.stack([texture(s) for s in shifts])
    flow = np.asarray(jaxsr.baselines.optical_flow(centre, neighbour))
    assert flow.shape == (3, 32, 64, 2)
    for f, s in zip(flow, shifts):
        inner = f[6:-6, 6:-6]  # away from the border, where part of the match leaves the frame
        err = np.hypot(inner[..., 0] - s[0], inner[..., 1] - s[1])
        assert np.median(err) < 0.1, (s, np.median(err))
        np.testing.assert_allclose(inner.reshape(-1, 2).mean(0), s, atol=0.05)


# --- HistNet's histogram features and the GAN losses --------------------------------------------------------------


def test_second_peak_depth_finds_the_weaker_return():
    sensor = Sensor()
    hist = np.full((2, 16), 2.0)
    hist[:, 3] += 60.0  # the first return, bin 3
    hist[0, 11] += 30.0  # a second return in the first pixel only
    first = np.asarray(jaxsr.centre_of_mass(jnp.asarray(hist), sensor))
    second = np.asarray(jaxsr.baselines.second_peak_depth(jnp.asarray(hist), sensor=sensor))
    np.testing.assert_allclose(first, 3.5 / 16, atol=1e-6)
    np.testing.assert_allclose(second, [11.5 / 16, 1.0], atol=1e-6)  # none in pixel 2: no return


def test_gan_losses_closed_forms():
    x = jnp.arange(8.0)[None, None, :] * 0.1 * jnp.ones((2, 4, 8))  # a ramp of slope 0.1 along x
    np.testing.assert_allclose(jaxsr.baselines.tv_loss(x), 2 * 0.1**2, rtol=1e-5)
    zeros = jnp.zeros((2,))
    np.testing.assert_allclose(jaxsr.baselines.discriminator_loss(zeros, zeros), 2 * np.log(2), rtol=1e-6)
    loss, parts = jaxsr.baselines.generator_loss(x, x, zeros)
    np.testing.assert_allclose(parts["adversarial"], np.log(2), rtol=1e-6)
    np.testing.assert_allclose(loss, 1e-3 * np.log(2) + 2e-8 * 2 * 0.1**2, rtol=1e-5)
    # a discriminator sure the fake is real costs the generator nothing adversarially
    assert float(jaxsr.baselines.generator_loss(x, x, jnp.full((2,), 30.0))[1]["adversarial"]) < 1e-12


# --- a few training steps lower the loss on a fixed batch ----------------------------------------------------------

SMALL_SENSOR = Sensor(optics=Optics.of_hr((32, 64)))


@jax.jit
def fixed_histogram_batch():
    """Expected histograms (2, 8, 16, 16) of a step-and-slope scene (a Gaussian return of 20 photons on 1 photon
    per bin of background; built directly: the full simulator is slow to compile), its HR intensity and GT."""
    x = jnp.linspace(0, 1, 64)[None, :]
    gt = jnp.broadcast_to(jnp.where(x < 0.5, 0.25, 0.6) + 0.1 * x, (2, 32, 64))  # normalised HR depth
    lr = gt.reshape(2, 8, 4, 16, 4).mean(axis=(2, 4))
    k = jnp.arange(16) + 0.5
    rates = 1.0 + 20.0 * jnp.exp(-0.5 * ((k - 16 * lr[..., None]) / 0.6) ** 2) / (0.6 * np.sqrt(2 * np.pi))
    return rates, jnp.full((2, 32, 64), 0.6), gt


def test_histnet_output_is_the_first_peak_depth_plus_the_residual():
    """With the last conv zeroed the network returns D1, the upsampled centre of mass of the LR histograms."""
    cfg = jaxsr.baselines.HistNetConfig(width=2)
    counts, intensity, _ = fixed_histogram_batch()
    params = jaxsr.baselines.init_histnet(jax.random.PRNGKey(1), cfg)
    params["out"] = jax.tree_util.tree_map(jnp.zeros_like, params["out"])
    out = jax.jit(lambda p: jaxsr.baselines.apply_histnet(p, counts, intensity, cfg, sensor=SMALL_SENSOR))(params)
    lr = jax.jit(jaxsr.centre_of_mass)(counts, SMALL_SENSOR)
    np.testing.assert_allclose(np.asarray(out), np.repeat(np.repeat(np.asarray(lr), 4, 1), 4, 2), atol=1e-6)


@pytest.mark.slow
def test_histnet_training_steps_lower_the_loss():
    cfg = jaxsr.baselines.HistNetConfig(width=4)
    batch = fixed_histogram_batch()
    step = jaxsr.training.make_histnet_train_step(cfg, lambda key: batch, schedule=lambda s: 1e-3, sensor=SMALL_SENSOR)
    params = jaxsr.baselines.init_histnet(jax.random.PRNGKey(1), cfg)
    opt = jaxsr.training.adam_init(params)
    losses = []
    for i in range(6):
        params, opt, m = step(params, opt, jax.random.PRNGKey(0), i)
        losses.append(float(m["loss"]))
    assert losses[-1] < 0.8 * losses[0], losses


@pytest.mark.slow
def test_iseebetter_training_steps_lower_the_content_loss():
    cfg = jaxsr.baselines.RBPNConfig(base_filter=8, feat=4, n_resblock=1, frames=3, disc_widths=(4, 4), disc_hidden=8,
                           flow_levels=2, flow_iterations=2)
    windows = jax.random.uniform(jax.random.PRNGKey(0), (2, 3, 8, 16))
    gt = jax.image.resize(windows[:, 1], (2, 32, 64), "linear")
    step = jaxsr.training.make_iseebetter_train_step(cfg, lambda key: (windows, gt), schedule=lambda s: 1e-3)
    g = jaxsr.baselines.init_rbpn(jax.random.PRNGKey(2), cfg)
    d, d_state = jaxsr.baselines.init_discriminator(jax.random.PRNGKey(3), cfg)
    nets, opts = (g, d, d_state), jaxsr.training.init_adam_pair(g, d)
    content = []
    for i in range(6):
        nets, opts, m = step(nets, opts, jax.random.PRNGKey(0), i)
        content.append(float(m["content"]))
        assert np.isfinite(float(m["d_loss"]))
    assert content[-1] < 0.5 * content[0], content


@pytest.mark.slow  # tracing the scene renderer alone takes ~6 s
def test_histogram_batches_shapes():
    train_cfg = dataclasses.replace(jaxsr.TrainConfig(), batch_size=2, patch=(8, 16))
    make_batch = jaxsr.training.histogram_batches(train_cfg)
    counts, intensity, gt = jax.eval_shape(make_batch, jax.random.PRNGKey(0))
    assert counts.shape == (2, 8, 16, 16) and intensity.shape == gt.shape == (2, 32, 64)


# --- trained baselines: files, the fit loop, the training script's plan -------------------------------------------

TINY_HISTNET = jaxsr.baselines.HistNetConfig(width=2)


def tiny_validation():
    counts, intensity, gt = fixed_histogram_batch()
    return {"counts": counts, "intensity": intensity, "gt": gt, "names": ["fixed"]}


def test_baselines_save_and_load_as_every_model_does(tmp_path):
    params = jaxsr.baselines.init_histnet(jax.random.PRNGKey(0), TINY_HISTNET)
    model = jaxsr.Model(params, {}, TINY_HISTNET)
    assert model.kind == "histnet" and model.architecture.inputs == "histograms"
    path = jaxsr.save_model(tmp_path / "h.npz", model, card={"steps": 3}, storage_dtype="float16")
    assert jaxsr.read_metadata(path)["architecture"] == "histnet"
    back = jaxsr.load_model(tmp_path / "h")  # without the suffix
    assert back.kind == "histnet" and back.config == TINY_HISTNET and back.state == {}
    assert jax.tree_util.tree_all(jax.tree_util.tree_map(lambda a, b: bool(jnp.allclose(a, b, atol=1e-2)),
                                                         back.params, params))
    # the same arrays under a config of another width: every shape is checked
    wrong = jaxsr.save_model(tmp_path / "w.npz", jaxsr.Model(params, {}, dataclasses.replace(TINY_HISTNET, width=4)))
    with pytest.raises(ValueError, match="shape"):
        jaxsr.load_model(wrong)
    path.write_bytes(path.read_bytes()[:200])  # truncated
    with pytest.raises(ValueError, match="truncated or corrupt"):
        jaxsr.load_model(path)
    with pytest.raises(ValueError, match="no registered architecture"):
        jaxsr.Model(params, {}, {"width": 2}).kind


def test_baselines_saved_by_jaxsr_0_1_still_load(tmp_path):
    """Files of kind "baseline" (params only, the kind in "baseline") load as a Model with empty state."""
    from jaxsr.io.checkpoint import config_to_dict, save_tree

    params = jaxsr.baselines.init_histnet(jax.random.PRNGKey(0), TINY_HISTNET)
    old = save_tree(tmp_path / "old.npz", {"params": params},
                    {"kind": "baseline", "baseline": "histnet", "config": config_to_dict(TINY_HISTNET), "card": {}})
    back = jaxsr.load_model(old)
    assert back.kind == "histnet" and back.state == {}
    np.testing.assert_array_equal(jax.tree_util.tree_leaves(back.params)[0], jax.tree_util.tree_leaves(params)[0])


def test_the_deprecated_baseline_names_warn_and_still_work(tmp_path):
    from jaxsr.training.baselines import BaselineModel, load_baseline, save_baseline

    params = jaxsr.baselines.init_histnet(jax.random.PRNGKey(0), TINY_HISTNET)
    with pytest.warns(DeprecationWarning, match="jaxsr.nn.Model"):
        model = BaselineModel("histnet", params, TINY_HISTNET)
    with pytest.warns(DeprecationWarning, match="save_model"):
        save_baseline(tmp_path / "h.npz", model)
    with pytest.warns(DeprecationWarning, match="load_model"):
        assert load_baseline(tmp_path / "h.npz").kind == "histnet"
    with pytest.warns(DeprecationWarning), pytest.raises(FileNotFoundError, match="train_baselines.py"):
        load_baseline(tmp_path / "nothing")
    with pytest.warns(DeprecationWarning), pytest.raises(ValueError, match="unknown baseline"):
        BaselineModel("duf", params, TINY_HISTNET)
    with pytest.warns(DeprecationWarning, match="moved to jaxsr.training.fit_baseline"):
        jaxsr.fit_baseline  # noqa: B018 (a former top-level name)


@pytest.mark.slow  # 10-18 s: keeps the default suite under 8 minutes on 2 cores
def test_one_fit_trains_a_baseline_checkpoints_every_epoch_resumes_and_refuses_other_settings(tmp_path):
    batch = fixed_histogram_batch()
    make_batch = lambda key: batch
    cfg1 = dataclasses.replace(jaxsr.TrainConfig(), batch_size=2, examples_per_epoch=4, epochs=1, decay_epochs=1)
    kw = {"make_batch": make_batch, "validation": tiny_validation(), "sensor": SMALL_SENSOR, "progress": False}
    _, hist1 = jaxsr.fit(TINY_HISTNET, cfg1, out=tmp_path, **kw)
    assert [r["step"] for r in hist1] == [2] and (tmp_path / "best.npz").is_file()
    with pytest.raises(FileExistsError, match="resume"):
        jaxsr.fit(TINY_HISTNET, cfg1, out=tmp_path, **kw)
    # resuming with a larger epoch budget continues from step 2; an uninterrupted 2-epoch run gives the same
    cfg2 = dataclasses.replace(cfg1, epochs=2)
    _model, hist2 = jaxsr.fit(TINY_HISTNET, cfg2, out=tmp_path, resume=True, **kw)
    _, straight = jaxsr.fit(TINY_HISTNET, cfg2, out=tmp_path / "straight", **kw)
    assert [r["step"] for r in hist2] == [2, 4]
    np.testing.assert_allclose([r["val_loss"] for r in hist2], [r["val_loss"] for r in straight], rtol=1e-5)
    card = jaxsr.read_metadata(tmp_path / "best.npz")["card"]
    assert card["steps"] == 4 and card["validation"]["frames"] == 2
    assert jaxsr.load_model(tmp_path / "best.npz").kind == "histnet"
    # finished: running again trains nothing
    assert len(jaxsr.fit(TINY_HISTNET, cfg2, out=tmp_path, resume=True, **kw)[1]) == 2
    with pytest.raises(ValueError, match="other settings.*lr"):
        jaxsr.fit(TINY_HISTNET, dataclasses.replace(cfg2, lr=1e-2), out=tmp_path, resume=True, **kw)
    with pytest.raises(ValueError, match="init.*DUF"):
        jaxsr.fit(TINY_HISTNET, cfg1, out=tmp_path / "warm", init="tr0", **kw)
    with pytest.raises(ValueError, match="pretrain_epochs is iSeeBetter's"):
        jaxsr.fit(TINY_HISTNET, cfg1, out=tmp_path / "pre", pretrain_epochs=1, **kw)


@pytest.mark.slow  # a GAN training run (9 s)
def test_one_fit_trains_iseebetter_as_a_gan_with_two_optimisers(tmp_path):
    cfg = jaxsr.baselines.RBPNConfig(base_filter=8, feat=4, n_resblock=1, frames=3, disc_widths=(4, 4),
                                     disc_hidden=8, flow_levels=2, flow_iterations=2)
    windows = jax.random.uniform(jax.random.PRNGKey(0), (2, 3, 8, 16))
    gt = jax.image.resize(windows[:, 1], (2, 32, 64), "linear")
    train_cfg = dataclasses.replace(jaxsr.TrainConfig(), batch_size=2, examples_per_epoch=4, epochs=2, patch=(8, 16))
    validation = {"windows": windows, "gt": gt, "lr": windows[:, 1], "names": ["fixed"]}
    kw = {"make_batch": lambda key: (windows, gt), "validation": validation, "sensor": SMALL_SENSOR, "progress": False}
    model, hist = jaxsr.fit(cfg, train_cfg, out=tmp_path, pretrain_epochs=1, **kw)
    assert model.kind == "iseebetter" and [r["step"] for r in hist] == [2, 4]
    assert "train_d_loss" not in hist[0] and np.isfinite(hist[1]["train_d_loss"])  # the GAN starts at epoch 2
    saved = jaxsr.read_metadata(tmp_path / "last.npz")
    assert saved["architecture"] == "iseebetter" and saved["pretrain_epochs"] == 1
    hr = jaxsr.super_resolve(jaxsr.load_model(tmp_path / "best.npz"), np.asarray(windows[:, 1]))
    assert hr.shape == (2, 32, 64) and np.all(np.isfinite(hr))
    assert "train_g_loss" not in hist[1]  # the generator's loss is the train loss
    # its config holds a tuple (disc_widths): the saved settings still match on resume
    _, more = jaxsr.fit(cfg, dataclasses.replace(train_cfg, epochs=3), out=tmp_path, pretrain_epochs=1, resume=True,
                        **kw)
    assert [r["step"] for r in more] == [2, 4, 6]
    with pytest.raises(ValueError, match="one device"):
        jaxsr.fit(cfg, train_cfg, out=tmp_path / "m", mesh=jaxsr.training.data_mesh(), **kw)


def test_info_describes_a_learned_baseline(capsys):
    from jaxsr import cli

    assert cli.main(["info", "histnet"]) == 0
    out = capsys.readouterr().out
    assert "histnet (a learned baseline)" in out and "parameters" in out


def _train_baselines_script():
    import train_baselines  # experiments/paper/train_baselines.py (pytest's pythonpath)

    return train_baselines


def test_train_baselines_plan_is_measured_once_and_read_back(tmp_path):
    script = _train_baselines_script()
    calls = []

    def measure():
        calls.append(1)
        return {"tr": 0.2, "baseline": 0.5}

    p = script.plan("histnet", tmp_path / "histnet", measure=measure)
    assert p["steps_per_epoch"] == math.ceil(p["tr_steps"] * 0.2 / 0.5 / 5) and p["comparable_tr"] == 0
    again = script.plan("histnet", tmp_path / "histnet", measure=measure)
    assert again == p and len(calls) == 1  # resuming reads plan.json, it does not time again
    assert script.train_config(p["steps_per_epoch"]).steps_per_epoch == p["steps_per_epoch"]
    with pytest.raises(ValueError, match="positive"):
        script.budget(1280, 0.2, 0.0)


def test_iseebetter_plan_prices_its_generator_only_epochs_at_their_own_step_time(tmp_path):
    script = _train_baselines_script()
    p = script.plan("iseebetter", tmp_path / "iseebetter",
                    measure=lambda: {"tr": 0.2, "baseline": 0.5, "generator": 0.25})
    pre = script.PRETRAIN_EPOCHS["iseebetter"]
    assert 0 < pre < script.EPOCHS and p["pretrain_epochs"] == pre and p["comparable_tr"] == 2
    mean = (pre * 0.25 + (script.EPOCHS - pre) * 0.5) / script.EPOCHS
    assert p["mean_step_s"] == pytest.approx(mean)
    assert p["steps_per_epoch"] == math.ceil(p["tr_steps"] * 0.2 / mean / script.EPOCHS)  # TR2's card steps


@pytest.mark.slow  # 30 s on 2 cores; test_one_fit_trains_iseebetter_as_a_gan_with_two_optimisers (slow too) sees the switch
def test_iseebetter_pretraining_moves_the_generator_alone_then_the_gan_starts():
    how = jaxsr.training.recipe("iseebetter")

    cfg = jaxsr.baselines.RBPNConfig(base_filter=8, feat=4, n_resblock=1, frames=3, disc_widths=(4, 4), disc_hidden=8,
                           flow_levels=2, flow_iterations=2)
    windows = jax.random.uniform(jax.random.PRNGKey(0), (2, 3, 8, 16))
    gt = jax.image.resize(windows[:, 1], (2, 32, 64), "linear")
    train_cfg = dataclasses.replace(jaxsr.TrainConfig(), batch_size=2, examples_per_epoch=2, patch=(8, 16))
    step = how.step(cfg, train_cfg, lambda key: (windows, gt), pretrain_steps=3)
    ts = how.init(jax.random.PRNGKey(1), cfg, None)
    disc0 = jax.device_get(ts["disc"])
    content = []
    for i in range(3):
        ts, m = step(ts, jax.random.PRNGKey(0), jnp.int32(i))
        content.append(float(m["content"]))
        assert "d_loss" not in m  # no discriminator step while pre-training
    assert content[-1] < content[0], content
    leaves = lambda t: jax.tree_util.tree_leaves(jax.device_get(t))  # noqa: E731
    assert all(np.array_equal(a, b) for a, b in zip(leaves(ts["disc"]), leaves(disc0)))
    ts, m = step(ts, jax.random.PRNGKey(0), jnp.int32(3))
    assert np.isfinite(float(m["d_loss"]))
    assert not all(np.array_equal(a, b) for a, b in zip(leaves(ts["disc"]), leaves(disc0)))
    with pytest.raises(ValueError, match="pretrain_epochs is iSeeBetter's"):
        jaxsr.training.recipe("histnet").step(jaxsr.baselines.HistNetConfig(width=4), train_cfg, lambda key: None,
                                              pretrain_steps=2)
