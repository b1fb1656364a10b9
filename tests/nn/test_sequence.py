"""The sequence form of the network (docs/network.md): its definition (a window loop of the same weights,
ends included), the stream, inference in the model's form, checkpoints of either form, training, FLOPs and bad
input."""

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsr import cli
from jaxsr.io.checkpoint import load_model, model_info, read_metadata, save_model
from jaxsr.config import ModelConfig, TrainConfig
from jaxsr.training.data import run_keys
from jaxsr.inference import Stream, iter_super_resolve, super_resolve
from jaxsr.nn import (
    Model,
    apply_model,
    apply_model_sequence,
    apply_model_sequence_train,
    flops_per_frame,
    grow_tr,
    init_model,
    sequence_radius,
)
from jaxsr.nn.streaming import stream_init, stream_step
from jaxsr.training import fit, sequence_loss

TINY = {"base": 8, "growth": 4, "head": 16, "filter_hidden": 16}
seq_jit = jax.jit(apply_model_sequence, static_argnums=3, static_argnames=("padding", "conv3d_impl"))
window_jit = jax.jit(apply_model, static_argnums=3, static_argnames="conv3d_impl")


def _model(tr, *, temporal="sequence", seed=0, **kw):
    """A tiny model with random running BN statistics (so that inference-mode BN is not the identity)."""
    cfg = ModelConfig(tr=tr, temporal=temporal, **{**TINY, **kw})
    params, state = init_model(jax.random.key(seed), cfg)
    keys = iter(jax.random.split(jax.random.key(seed + 1), 64))
    state = jax.tree_util.tree_map(lambda x: x + 0.3 * jax.random.uniform(next(keys), x.shape), state)
    return Model(params, state, cfg)


def _lr(frames, seed=0, shape=(4, 6)):
    return np.asarray(jax.random.uniform(jax.random.key(100 + seed), (frames, *shape)))


def _window_loop(model, seq):
    """The definition: output t is the network with all 3 + tr blocks temporally valid (the windowed network
    with same_blocks=0 and radius R), applied to the window t-R .. t+R with indices clipped to the sequence
    by hand, one window at a time, with XLA's own 3D convolutions."""
    r = sequence_radius(model.config)
    cfg = dataclasses.replace(model.config, tr=r, same_blocks=0, temporal="window")
    t_max = seq.shape[0] - 1
    out = []
    for t in range(seq.shape[0]):
        idx = [min(max(s, 0), t_max) for s in range(t - r, t + r + 1)]
        out.append(window_jit(model.params, model.state, jnp.asarray(seq[idx])[None], cfg, conv3d_impl="native")[0])
    return np.stack(out)


@pytest.mark.parametrize("tr,frames", [(0, 1), (2, 12)])
def test_sequence_form_equals_the_window_loop_ends_included(tr, frames):
    model = _model(tr)
    seq = _lr(frames, tr)
    out = seq_jit(model.params, model.state, jnp.asarray(seq)[None], model.config)[0]
    assert out.shape == (frames, 16, 24)
    np.testing.assert_allclose(out, _window_loop(model, seq), rtol=1e-5, atol=2e-6)
    if frames >= 2 * sequence_radius(model.config) + 1:  # "valid": the outputs whose inputs lie inside
        r = sequence_radius(model.config)
        valid = seq_jit(model.params, model.state, jnp.asarray(seq)[None], model.config, padding="valid")[0]
        np.testing.assert_allclose(valid, out[r:-r], rtol=1e-5, atol=2e-6)


def test_dynamic_filter_reads_frame_t():
    """Zero residual and filters saturated on the centre tap: output t is LR frame t, nearest-upsampled."""
    model = _model(1)
    params = jax.tree_util.tree_map(lambda x: x, model.params)
    r2 = 16
    params["residual"]["conv2"] = {"w": jnp.zeros_like(params["residual"]["conv2"]["w"]), "b": jnp.zeros(r2)}
    logits = jnp.full((25, r2), -1e4).at[12].set(0.0).reshape(-1)
    params["filter"]["conv2"] = {"w": jnp.zeros_like(params["filter"]["conv2"]["w"]), "b": logits}
    seq = _lr(4, 7)
    out = seq_jit(params, model.state, jnp.asarray(seq)[None], model.config)[0]
    np.testing.assert_allclose(out, np.repeat(np.repeat(seq, 4, axis=1), 4, axis=2), rtol=1e-6)


@pytest.mark.parametrize("frames", [1, 4, 9])
def test_stream_equals_the_sequence_form(frames):
    """R = 4 for tr=1: fewer, as many and more frames than the stream's latency."""
    model = _model(1)
    seq = _lr(frames, frames)
    ref = np.asarray(seq_jit(model.params, model.state, jnp.asarray(seq)[None], model.config)[0])
    stream = Stream(model)
    assert stream.latency == 4
    pushed = [stream.push(f) for f in seq]
    assert all(hr is None for hr in pushed[:4]) and all(hr is not None for hr in pushed[4:])
    tail = stream.flush()
    assert len(tail) == min(frames, 4)
    np.testing.assert_allclose(np.stack([hr for hr in pushed if hr is not None] + tail), ref, rtol=1e-5, atol=2e-6)
    # after a flush the same object streams a new sequence from scratch
    again = [stream.push(f) for f in seq[::-1]]
    again = [hr for hr in again if hr is not None] + stream.flush()
    ref_rev = np.asarray(seq_jit(model.params, model.state, jnp.asarray(seq[::-1])[None], model.config)[0])
    np.testing.assert_allclose(np.stack(again), ref_rev, rtol=1e-5, atol=2e-6)


def test_stream_step_batched_with_fixed_memory():
    """The pure step on two streams at once: buffers keep their shapes, outputs match the sequence form."""
    model = _model(0)
    r = sequence_radius(model.config)
    seqs = jnp.stack([jnp.asarray(_lr(5, 1)), jnp.asarray(_lr(5, 2))])  # (2, 5, h, w)
    padded = jnp.concatenate([jnp.repeat(seqs[:, :1], r, 1), seqs, jnp.repeat(seqs[:, -1:], r, 1)], axis=1)
    buffers = stream_init(model.config, (4, 6), batch=2)
    shapes = jax.tree_util.tree_map(jnp.shape, buffers)
    step = jax.jit(stream_step, static_argnums=4)
    outs = []
    for n in range(padded.shape[1]):
        buffers, hr = step(model.params, model.state, buffers, padded[:, n], model.config)
        outs.append(hr)
    assert jax.tree_util.tree_map(jnp.shape, buffers) == shapes
    ref = seq_jit(model.params, model.state, seqs, model.config)
    np.testing.assert_allclose(jnp.stack(outs[2 * r:], axis=1), ref, rtol=1e-5, atol=2e-6)


def test_super_resolve_runs_the_models_form():
    """A sequence-form model: `super_resolve` in chunks of any size (overlapping by 2R) equals the sequence
    form on the whole sequence; the same weights as a window-form model give the window form."""
    model = _model(1)
    seq = _lr(11, 3)
    ref = np.asarray(seq_jit(model.params, model.state, jnp.asarray(seq)[None], model.config)[0])
    for batch in (None, 8):  # one chunk of 11; chunks of 8 and of 3 (run as 4)
        np.testing.assert_allclose(super_resolve(model, seq, batch_size=batch), ref, rtol=1e-5, atol=2e-6)
    streamed = np.stack(list(iter_super_resolve(model, iter(seq), batch_size=1)))  # a generator: no len()
    np.testing.assert_allclose(streamed, ref, rtol=1e-5, atol=2e-6)
    windowed = Model(model.params, model.state, dataclasses.replace(model.config, temporal="window"))
    w = np.asarray(window_jit(windowed.params, windowed.state, jax.numpy.asarray(seq[[0, 0, 1]])[None],
                              windowed.config))[0]
    np.testing.assert_allclose(super_resolve(windowed, seq)[0], w, rtol=1e-5, atol=2e-6)
    assert np.abs(super_resolve(windowed, seq) - ref).max() > 1e-5  # another function of the same weights


def _strip_temporal(path):
    """Rewrite a checkpoint's metadata as versions before the sequence form wrote it: no `temporal` field."""
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(str(arrays["__metadata__"]))
    del meta["config"]["temporal"]
    arrays["__metadata__"] = np.array(json.dumps(meta))
    np.savez(path, **arrays)


def test_windowed_checkpoint_loads_into_the_sequence_form(tmp_path, capsys):
    windowed = _model(1, temporal="window")
    path = save_model(tmp_path / "w.npz", windowed)
    _strip_temporal(path)  # as older versions wrote it: read as the window form
    assert load_model(path).config.temporal == "window"
    model = load_model(path, temporal="sequence")
    assert model.config == dataclasses.replace(windowed.config, temporal="sequence")
    for a, b in zip(jax.tree_util.tree_leaves(model), jax.tree_util.tree_leaves(windowed)):
        np.testing.assert_array_equal(a, b)
    seq = _lr(6, 4)
    np.testing.assert_allclose(super_resolve(model, seq), _window_loop(windowed, seq), rtol=1e-5, atol=2e-6)
    # a sequence-form model keeps its form through a file, and `jaxsr info` says so
    save_model(tmp_path / "s.npz", model)
    assert load_model(tmp_path / "s.npz").config.temporal == "sequence"
    info = model_info(tmp_path / "s.npz", lr_shape=(4, 6))
    assert info["temporal"] == "sequence" and info["input_radius"] == 4 and info["config"]["temporal"] == "sequence"
    assert info["gflops_per_frame"] == round(flops_per_frame(model.config, (4, 6)) / 1e9, 3)
    assert model_info(path)["config"]["temporal"] == "window"
    assert cli.main(["info", str(tmp_path / "s.npz")]) == 0
    assert "TR 1 (sequence form: frame t from frames t-4 .. t+4, stream latency 4 frames)" in capsys.readouterr().out


def test_sequence_loss_gradients_are_finite_and_those_of_the_window_loop():
    model = _model(0)
    r = sequence_radius(model.config)
    clips = jnp.asarray(np.stack([_lr(2 * r + 3, 5), _lr(2 * r + 3, 6)]))
    gt = jax.random.uniform(jax.random.key(9), (2, 2 * r + 3, 16, 24))
    loss_and_grad = jax.jit(jax.value_and_grad(sequence_loss, has_aux=True), static_argnums=4)
    (_, (new_state, hr, gt_used)), grads = loss_and_grad(model.params, model.state, clips, gt, model.config)
    assert hr.shape == gt_used.shape == (2, 3, 16, 24)
    leaves = jax.tree_util.tree_leaves(grads)
    assert all(bool(jnp.all(jnp.isfinite(g))) for g in leaves) and any(float(jnp.abs(g).max()) > 0 for g in leaves)
    # BN in training mode normalises with the clip's statistics and moves the running ones
    assert not np.allclose(new_state["blocks"][0]["bn1"]["mean"], model.state["blocks"][0]["bn1"]["mean"])
    # inference mode: the gradient of the sequence form is the gradient of the window loop (the definition)
    cfg_w = dataclasses.replace(model.config, tr=r, same_blocks=0, temporal="window")
    windows = clips[0][jnp.arange(3)[:, None] + jnp.arange(2 * r + 1)[None, :]]

    def seq_loss(p):
        return jnp.mean((apply_model_sequence(p, model.state, clips[:1], model.config, padding="valid")[0] - 0.5) ** 2)

    def loop_loss(p):
        return jnp.mean((apply_model(p, model.state, windows, cfg_w, conv3d_impl="native") - 0.5) ** 2)

    for a, b in zip(jax.tree_util.tree_leaves(jax.jit(jax.grad(seq_loss))(model.params)),
                    jax.tree_util.tree_leaves(jax.jit(jax.grad(loop_loss))(model.params))):
        np.testing.assert_allclose(a, b, rtol=2e-4, atol=1e-6)


def toy_clips(frames, batch, *, lr_shape=(8, 16), scale=4, noise=0.1):
    """Clips of a rectangle at a random depth before a far wall, drifting one LR pixel per frame; LR = its 4x4
    block mean plus Gaussian noise; gt per frame. Pure and jittable, like `jaxsr.training.data.scene_clips`."""
    hh, ww = lr_shape[0] * scale, lr_shape[1] * scale
    yy, xx = jnp.mgrid[:hh, :ww]

    def example(key):
        k = jax.random.split(key, 4)
        y0 = jax.random.randint(k[0], (), 0, hh // 2)
        x0 = jax.random.randint(k[1], (), 0, ww // 4)
        d = jax.random.uniform(k[2], (), minval=0.1, maxval=0.6)
        x = x0 + scale * jnp.arange(frames)[:, None, None]
        hr = jnp.where((yy >= y0) & (yy < y0 + hh // 3) & (xx >= x) & (xx < x + ww // 3), d, 0.9)
        lr = hr.reshape(frames, lr_shape[0], scale, lr_shape[1], scale).mean(axis=(2, 4))
        return jnp.clip(lr + noise * jax.random.normal(k[3], lr.shape), 0, 1), hr  # normalised depth, as the COM

    def make_batch(key):
        return jax.vmap(example)(jax.random.split(key, batch))

    return make_batch


SEQ_TINY = ModelConfig(tr=0, bn_momentum=0.9, temporal="sequence", **TINY)


def _toy_setup(n_val=6):
    clip = 2 * sequence_radius(SEQ_TINY) + 2
    val_lr, val_gt = toy_clips(2 * n_val, 1)(jax.random.key(7))
    # two validation sequences end to end
    val = {"lr": val_lr[0], "gt": val_gt[0], "names": ["a", "b"], "lengths": [n_val, n_val]}
    return clip, val


@pytest.mark.slow  # a training run in the sequence form (9 s)
def test_fit_in_the_sequence_form_fine_tunes_a_windowed_model(tmp_path):
    """`fit(init=...)` starts from a windowed checkpoint's weights (lr 0 keeps them: BN statistics still move),
    trains on clips, validates on whole sequences, and records the form and the init."""
    cfg = SEQ_TINY
    windowed = _model(0, temporal="window", bn_momentum=0.9)
    init = save_model(tmp_path / "w.npz", windowed)
    clip, val = _toy_setup()
    train = TrainConfig(batch_size=2, examples_per_epoch=2, epochs=1, lr=0.0, val_frames=6, clip_frames=clip)
    model, hist = fit(cfg, train, out=tmp_path / "a", make_batch=toy_clips(clip, 2), validation=val,
                      progress=False, init=init)
    for a, b in zip(jax.tree_util.tree_leaves(model.params), jax.tree_util.tree_leaves(windowed.params)):
        np.testing.assert_array_equal(a, b)
    assert load_model(tmp_path / "a" / "best.npz").config.temporal == "sequence"
    assert read_metadata(tmp_path / "a" / "best.npz")["card"]["init"] == str(init)
    assert np.isfinite(hist[0]["val_loss"]) and hist[0]["val_psnr"] > 0
    # a smaller TR is grown (`grow_tr`: its weights carried over, the added block drawn); a larger one or another
    # width cannot be the starting point
    grown, _ = fit(dataclasses.replace(cfg, tr=1), train, out=tmp_path / "c", make_batch=toy_clips(clip + 2, 2),
                   validation=val, progress=False, init=init)
    np.testing.assert_array_equal(grown.params["stem"]["w"], windowed.params["stem"]["w"])
    # lr 0: the weights are those fit grew, with the key `run_keys` names for the initial weights
    expect = grow_tr(run_keys(train.seed)[0], windowed, 1)
    for a, b in zip(jax.tree_util.tree_leaves(grown.params), jax.tree_util.tree_leaves(expect.params)):
        np.testing.assert_array_equal(a, b)
    assert len(grown.params["blocks"]) == len(windowed.params["blocks"]) + 1
    with pytest.raises(ValueError, match=r"architecture differs from the model to train: tr 1 \(training 0\)"):
        fit(cfg, train, out=tmp_path / "d", make_batch=toy_clips(clip, 2), validation=val, progress=False,
            init=tmp_path / "c" / "best.npz")
    with pytest.raises(ValueError, match=r"architecture differs from the model to train: growth"):
        fit(dataclasses.replace(cfg, tr=1, growth=cfg.growth + 1), train, out=tmp_path / "e",
            make_batch=toy_clips(clip + 2, 2), validation=val, progress=False, init=init)


@pytest.mark.slow  # about a minute on 2 busy cores
def test_fit_in_the_sequence_form_learns(tmp_path):
    clip, val = _toy_setup()
    train = TrainConfig(batch_size=2, examples_per_epoch=40, epochs=3, lr=3e-3, val_frames=6, clip_frames=clip)
    _, hist = fit(SEQ_TINY, train, out=tmp_path, make_batch=toy_clips(clip, 2), validation=val, progress=False)
    assert hist[-1]["train_loss"] < 0.75 * hist[0]["train_loss"], hist
    assert min(r["val_loss"] for r in hist[1:]) < hist[0]["val_loss"], hist


def test_flops_of_the_sequence_form():
    """The counts (GFLOP per 32 x 64 frame, each layer computing each frame once), a clip's count
    tending to them, and the TR4 count about a third of the windowed one."""
    expect = {1: 5.3, 2: 6.4, 3: 7.7, 4: 9.2}
    for tr, gflop in expect.items():
        cfg = ModelConfig(tr=tr, temporal="sequence")
        assert flops_per_frame(cfg) / 1e9 == pytest.approx(gflop, abs=0.05)
        r = sequence_radius(cfg)
        clips = [flops_per_frame(cfg, clip_frames=2 * r + k) for k in (1, 8, 1000)]
        assert clips[0] > clips[1] > clips[2] == pytest.approx(flops_per_frame(cfg), rel=0.01)
    ratio = flops_per_frame(ModelConfig(tr=4)) / flops_per_frame(ModelConfig(tr=4, temporal="sequence"))
    assert 3.0 < ratio < 3.2


def test_flops_of_a_clip_match_xla():
    """The analytic count of one clip agrees with XLA's cost analysis of `apply_model_sequence` (paper widths)."""
    cfg = ModelConfig(tr=0, temporal="sequence")
    params, state = init_model(jax.random.key(0), cfg)
    x = jnp.zeros((1, 9, 32, 64))
    cost = seq_jit.lower(params, state, x, cfg, padding="valid", conv3d_impl="taps").compile().cost_analysis()
    cost = cost[0] if isinstance(cost, list) else cost
    assert 3 * flops_per_frame(cfg, clip_frames=9) == pytest.approx(cost["flops"], rel=0.03)


def test_bad_input_is_refused_clearly():
    model = _model(1)
    p, s, cfg = model.params, model.state, model.config
    with pytest.raises(ValueError, match=r"expected an LR sequence \(B, T, H, W\) with T >= 9 .*'valid' \(R = 4\)"):
        apply_model_sequence(p, s, jnp.zeros((1, 8, 4, 6)), cfg, padding="valid")
    with pytest.raises(ValueError, match=r"apply_model_sequence: expected an LR sequence \(B, T, H, W\)"):
        apply_model_sequence(p, s, jnp.zeros((8, 4, 6)), cfg)
    with pytest.raises(ValueError, match="apply_model_sequence_train: expected an LR sequence"):
        apply_model_sequence_train(p, s, jnp.zeros((1, 5, 4, 6)), cfg)
    with pytest.raises(ValueError, match="padding must be 'edge' or 'valid', got 'same'"):
        apply_model_sequence(p, s, jnp.zeros((1, 8, 4, 6)), cfg, padding="same")
    with pytest.raises(ValueError, match="conv3d_impl must be one of"):
        apply_model_sequence(p, s, jnp.zeros((1, 8, 4, 6)), cfg, conv3d_impl="fft")
    with pytest.raises(ValueError, match=r"stream_step: expected a frame \(B, h, w\) = \(1, 4, 6\)"):
        stream_step(p, s, stream_init(cfg, (4, 6)), jnp.zeros((1, 5, 6)), cfg)
    stream = Stream(model)
    with pytest.raises(ValueError, match="no frame was pushed; a stream needs at least one LR frame"):
        stream.flush()
    stream.push(np.zeros((4, 6)))
    with pytest.raises(ValueError, match=r"frame 1 has shape \(5, 6\), expected \(4, 6\)"):
        stream.push(np.zeros((5, 6)))
    with pytest.raises(ValueError, match=r"frame 1 has values in \[12, 12\], outside \[0, 1\]"):
        stream.push(np.full((4, 6), 12.0))  # metres, not normalised depth
    with pytest.raises(ValueError, match="temporal must be one of"):
        ModelConfig(temporal="recurrent")
    with pytest.raises(ValueError, match=r"clip_frames must be at least 2R \+ 1 = 9 for tr=1"):
        TrainConfig(clip_frames=8).clip_length(cfg)
    with pytest.raises(ValueError, match="clip_frames applies to the sequence form only"):
        flops_per_frame(ModelConfig(), clip_frames=20)
    with pytest.raises(ValueError, match=r"sequence_loss: expected gt \(B, L, H, W\)"):
        sequence_loss(p, s, jnp.zeros((1, 9, 4, 6)), jnp.zeros((1, 16, 24)), cfg)


def test_train_command_checks_the_clip_before_any_training(tmp_path, capsys):
    out = tmp_path / "run"
    assert cli.main(["train", "--tr", "4", "--temporal", "sequence", "--clip-frames", "14", "--output", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("jaxsr train: error: ") and "clip_frames must be at least 2R + 1 = 15" in err
    assert not out.exists()
