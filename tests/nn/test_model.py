"""The network: parameter counts of docs/network.md, shapes for TR0-4 and scale 8, BN modes, hand-set weights."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsr.config import ModelConfig, TrainConfig
from jaxsr.nn import (Model, apply_model, apply_model_sequence, apply_model_train, count_params,
                         flops_per_frame, grow_tr, init_model)
from jaxsr.temporal import windows as temporal_windows

TINY = dict(base=8, growth=4, head=16, filter_hidden=16)
# jit once per config: much faster than op-by-op dispatch of the whole network
apply_jit = jax.jit(apply_model, static_argnums=3, static_argnames="conv3d_impl")
train_jit = jax.jit(apply_model_train, static_argnums=3, static_argnames="conv3d_impl")
PAPER_COUNTS = {0: 1_056_608, 1: 1_295_072, 2: 1_572_608, 3: 1_891_264, 4: 2_253_088}


def _shapes(cfg):
    return jax.eval_shape(lambda k: init_model(k, cfg), jax.random.key(0))


@pytest.mark.parametrize("tr", sorted(PAPER_COUNTS))
def test_parameter_counts(tr):
    params, _ = _shapes(ModelConfig(tr=tr))
    assert count_params(params) == PAPER_COUNTS[tr]


def test_key_paths_and_state():
    params, state = _shapes(ModelConfig(tr=2))
    assert len(params["blocks"]) == 5 and params["blocks"][0]["conv2"]["w"].shape == (3, 3, 3, 64, 32)
    assert params["blocks"][4]["conv2"]["w"].shape == (3, 3, 3, 192, 32)
    assert params["head"]["conv"]["w"].shape == (1, 3, 3, 224, 256)
    assert params["filter"]["conv2"]["w"].shape == (1, 1, 1, 512, 25 * 16)
    assert state["blocks"][4]["bn2"]["var"].shape == (192,)


@pytest.mark.parametrize("tr,scale", [(0, 4), (1, 4), (2, 4), (3, 4), (4, 4), (2, 8)])
def test_shapes_full_size(tr, scale):
    cfg = ModelConfig(tr=tr, scale=scale)
    params, state = _shapes(cfg)
    lr = (128 // scale, 256 // scale)
    win = jax.ShapeDtypeStruct((2, 2 * tr + 1, *lr), jnp.float32)
    out = jax.eval_shape(lambda p, s, w: apply_model(p, s, w, cfg), params, state, win)
    assert out.shape == (2, 128, 256)
    hr, new_state = jax.eval_shape(lambda p, s, w: apply_model_train(p, s, w, cfg), params, state, win)
    assert hr.shape == (2, 128, 256)
    assert jax.tree_util.tree_structure(new_state) == jax.tree_util.tree_structure(state)


@pytest.mark.parametrize("tr,scale", [(0, 4), (2, 4), (1, 8)])
def test_tiny_forward_runs(tr, scale):
    cfg = ModelConfig(tr=tr, scale=scale, **TINY)
    params, state = init_model(jax.random.key(0), cfg)
    win = jax.random.uniform(jax.random.key(1), (2, cfg.frames, 4, 6))
    hr = apply_jit(params, state, win, cfg)
    assert hr.shape == (2, 4 * scale, 6 * scale) and bool(jnp.all(jnp.isfinite(hr)))
    hr_t, new_state = train_jit(params, state, win, cfg)
    # training mode uses batch statistics (differs from the running ones) and moves the running mean
    assert not np.allclose(hr_t, hr)
    assert not np.allclose(new_state["blocks"][1]["bn1"]["mean"], state["blocks"][1]["bn1"]["mean"])
    # inference is deterministic and leaves no state behind
    np.testing.assert_array_equal(apply_jit(params, state, win, cfg), hr)


def test_conv3d_impls_give_same_network():
    cfg = ModelConfig(tr=1, **TINY)
    params, state = init_model(jax.random.key(0), cfg)
    win = jax.random.uniform(jax.random.key(1), (2, 3, 4, 6))
    a = apply_jit(params, state, win, cfg, conv3d_impl="native")
    b = apply_jit(params, state, win, cfg, conv3d_impl="taps")
    np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5)
    # the training form too, batch statistics and all
    (a_t, sa), (b_t, sb) = (train_jit(params, state, win, cfg, conv3d_impl=i) for i in ("native", "taps"))
    np.testing.assert_allclose(a_t, b_t, rtol=1e-4, atol=1e-5)
    for x, y in zip(jax.tree_util.tree_leaves(sa), jax.tree_util.tree_leaves(sb)):
        np.testing.assert_allclose(x, y, rtol=1e-4, atol=1e-5)


@pytest.mark.slow  # 86 s on 2 Intel Xeon cores, a sixth of the default suite's time there
def test_precisions_of_the_network():
    """The network at each precision: float32 output everywhere, bfloat16 products within bfloat16's band of the
    default, every form (window, sequence, stream) taking the argument, and an unknown precision refused."""
    from jaxsr.nn import stream_init, stream_step
    from jaxsr.training.duf import default_data, make_train_step
    from jaxsr.training.optim import adam_init
    cfg = ModelConfig(tr=1, **TINY)
    params, state = init_model(jax.random.key(0), cfg)
    win = jax.random.uniform(jax.random.key(1), (2, 3, 4, 6))
    ref = apply_model(params, state, win, cfg)
    for precision, tol in (("float32", 1e-5), ("bfloat16", 3e-2)):
        hr = apply_model(params, state, win, cfg, precision=precision)
        assert hr.dtype == jnp.float32
        assert float(jnp.linalg.norm(hr - ref) / jnp.linalg.norm(ref)) < tol
        seq = apply_model_sequence(params, state, win, cfg, precision=precision)
        assert seq.dtype == jnp.float32 and bool(jnp.all(jnp.isfinite(seq)))
        _, out = stream_step(params, state, stream_init(cfg, (4, 6), batch=2), win[:, 0], cfg, precision=precision)
        assert out.dtype == jnp.float32
    # every product of the network, its dynamic filter included, at the precision asked for
    from test_layers import products
    highest = "(Precision.HIGHEST, Precision.HIGHEST)"
    found = products(lambda p: apply_model(p, state, win, cfg, precision="float32"), params)
    assert found and {prec for _, _, prec in found} == {highest}
    found = products(lambda p: apply_model(p, state, win, cfg, precision="bfloat16"), params)
    assert {dtypes for name, dtypes, _ in found if name == "conv_general_dilated"} == {("bfloat16", "bfloat16")}
    with pytest.raises(ValueError, match="precision"):
        apply_model(params, state, win, cfg, precision="half")
    with pytest.raises(ValueError, match="precision"):
        TrainConfig(precision="tf32")
    # a training step at bfloat16 keeps float32 weights and state, and its loss is finite
    train_cfg = TrainConfig(batch_size=2, examples_per_epoch=2, patch=(4, 6), precision="bfloat16")
    step = make_train_step(cfg, train_cfg, default_data(cfg, train_cfg))
    p2, s2, _, metrics = step(params, state, adam_init(params), jax.random.key(2), jnp.int32(0))
    assert np.isfinite(float(metrics["loss"]))
    assert {str(a.dtype) for a in jax.tree_util.tree_leaves((p2, s2))} == {"float32"}


def test_hand_set_head_gives_nearest_upsampling_of_centre_frame():
    """Zero residual and a filter branch saturated on the centre tap: the output is the centre input frame,
    nearest-upsampled (the other frames of the window do not leak into the filtered path)."""
    cfg = ModelConfig(tr=2, **TINY)
    params, state = init_model(jax.random.key(0), cfg)
    r2 = cfg.scale**2
    params["residual"]["conv2"] = {"w": jnp.zeros_like(params["residual"]["conv2"]["w"]), "b": jnp.zeros(r2)}
    logits = jnp.full((25, r2), -1e4).at[12].set(0.0).reshape(-1)
    params["filter"]["conv2"] = {"w": jnp.zeros_like(params["filter"]["conv2"]["w"]), "b": logits}
    win = jax.random.uniform(jax.random.key(1), (2, 5, 3, 4))
    hr = apply_jit(params, state, win, cfg)
    expect = jnp.repeat(jnp.repeat(win[:, 2], 4, axis=1), 4, axis=2)
    np.testing.assert_allclose(hr, expect, rtol=1e-6)
    # a constant residual is added unclipped, without activation
    params["residual"]["conv2"]["b"] = jnp.full(r2, -2.0)
    np.testing.assert_allclose(apply_jit(params, state, win, cfg), expect - 2.0, rtol=1e-6)


def test_bad_window_shape_raises():
    cfg = ModelConfig(tr=1, **TINY)
    params, state = init_model(jax.random.key(0), cfg)
    with pytest.raises(ValueError, match=r"\(B, 3, H, W\)"):
        apply_model(params, state, jnp.zeros((2, 5, 4, 4)), cfg)
    with pytest.raises(ValueError):
        apply_model(params, state, jnp.zeros((3, 4, 4)), cfg)
    with pytest.raises(ValueError, match=r"apply_model_train: expected windows \(B, 3, H, W\)"):
        apply_model_train(params, state, jnp.zeros((2, 5, 4, 4)), cfg)
    # how to run is checked before anything runs, and the message lists the choices
    for f in (apply_model, apply_model_train):
        with pytest.raises(ValueError, match=r"conv3d_impl must be one of 'auto', 'native', 'taps', 'stacked', "
                                             r"'stacked-taps-grad', got 'fft'"):
            f(params, state, jnp.zeros((2, 3, 4, 4)), cfg, conv3d_impl="fft")


def test_config_validation():
    with pytest.raises(ValueError):
        ModelConfig(tr=-1)
    with pytest.raises(ValueError):
        ModelConfig(filter_size=4)
    with pytest.raises(ValueError):
        ModelConfig(filter_padding="reflect")
    assert ModelConfig(tr=3).features == 64 + 32 * 6


def test_temporal_windows_edge_replicated():
    seq = jnp.arange(4.0)[:, None, None] * jnp.ones((4, 2, 3))
    w = temporal_windows(seq, 2)
    assert w.shape == (4, 5, 2, 3)
    np.testing.assert_array_equal(w[:, :, 0, 0], [[0, 0, 0, 1, 2], [0, 0, 1, 2, 3], [0, 1, 2, 3, 3], [1, 2, 3, 3, 3]])


def test_model_is_a_pytree():
    cfg = ModelConfig(tr=1, **TINY)
    model = Model(*init_model(jax.random.key(0), cfg), cfg)
    leaves, treedef = jax.tree_util.tree_flatten(model)
    assert len(leaves) == len(jax.tree_util.tree_leaves((model.params, model.state)))
    assert jax.tree_util.tree_unflatten(treedef, leaves).config == cfg


def test_the_measured_forms_are_static_and_travel_with_the_weights():
    """`Model.equivalent_forms` (the forms measured to keep the weights' accuracy): () by default, a static field
    (in the tree's structure, not its leaves), kept by `in_form`, `dataclasses.replace` and tree maps."""
    import dataclasses

    cfg = ModelConfig(tr=1, **TINY)
    model = Model(*init_model(jax.random.key(0), cfg), cfg)
    assert model.equivalent_forms == ()
    measured = Model(model.params, model.state, cfg, ["sequence"])
    assert measured.equivalent_forms == ("sequence",) and hash(measured.equivalent_forms)
    leaves, treedef = jax.tree_util.tree_flatten(measured)
    assert len(leaves) == len(jax.tree_util.tree_leaves(model)) and treedef != jax.tree_util.tree_structure(model)
    assert jax.tree_util.tree_unflatten(treedef, leaves).equivalent_forms == ("sequence",)
    assert jax.tree_util.tree_map(lambda x: x, measured).equivalent_forms == ("sequence",)
    seq = measured.in_form("sequence")
    assert seq.form == "sequence" and seq.equivalent_forms == ("sequence",) and seq.in_form("window").config == cfg
    assert dataclasses.replace(measured, params={}).equivalent_forms == ("sequence",)


@pytest.mark.parametrize("tr", [0, 1])
def test_flops_per_frame_matches_xla(tr):
    """The analytic count agrees with XLA's own cost analysis of the compiled network at the paper's widths
    (within 3 %: batch norm, ReLU and softmax are not counted, and XLA skips taps in the zero padding).
    The count is the network's arithmetic, as "taps" computes it; "stacked" layers compute some products twice."""
    cfg = ModelConfig(tr=tr)
    params, state = init_model(jax.random.key(0), cfg)
    x = jnp.zeros((1, cfg.frames, 32, 64))  # the sensor's frame: XLA skips taps in the spatial zero padding
    cost = apply_jit.lower(params, state, x, cfg, conv3d_impl="taps").compile().cost_analysis()
    cost = cost[0] if isinstance(cost, list) else cost
    assert flops_per_frame(cfg) == pytest.approx(cost["flops"], rel=0.03)


def _trained_like(cfg, seed):
    """Random weights with every leaf moved off its initial value (BN scales and shifts, biases, running
    statistics), standing in for a trained model. The offsets come from NumPy: a JAX draw per leaf shape compiled
    one kernel per shape (8 s)."""
    params, state = init_model(jax.random.key(seed), cfg)
    leaves, tree = jax.tree_util.tree_flatten((params, state))
    rng = np.random.default_rng(seed + 100)
    params, state = jax.tree_util.tree_unflatten(
        tree, [x + np.float32(0.1) * np.abs(rng.standard_normal(x.shape, np.float32)) for x in leaves])
    return Model(params, state, cfg)


def test_grow_tr_has_the_larger_networks_shapes_and_refuses_to_shrink():
    cfg = ModelConfig(tr=0, **TINY)
    grown = grow_tr(jax.random.key(1), _trained_like(cfg, 0), 2)
    ref = init_model(jax.random.key(2), ModelConfig(tr=2, **TINY))
    assert grown.config == ModelConfig(tr=2, **TINY)
    assert jax.tree_util.tree_structure((grown.params, grown.state)) == jax.tree_util.tree_structure(ref)
    assert [x.shape for x in jax.tree_util.tree_leaves((grown.params, grown.state))] == \
        [x.shape for x in jax.tree_util.tree_leaves(ref)]
    with pytest.raises(ValueError, match="tr must be >= the model's 2"):
        grow_tr(jax.random.key(3), grown, 1)


@pytest.mark.slow  # 15 s of compiles in both forms
def test_grow_tr_starts_from_the_trained_function_in_the_sequence_form():
    """The added block's features reach the head through zero weights: the grown TR1 computes the TR0's output
    exactly, cropped by the added radius (1 frame) at each end."""
    cfg = ModelConfig(tr=0, temporal="sequence", **TINY)
    small = _trained_like(cfg, 0)
    grown = grow_tr(jax.random.key(1), small, 1)
    lr = jax.random.uniform(jax.random.key(4), (2, 12, 6, 8))
    out_small = apply_model_sequence(small.params, small.state, lr, cfg, padding="valid")
    out_grown = apply_model_sequence(grown.params, grown.state, lr, grown.config, padding="valid")
    np.testing.assert_allclose(out_grown, out_small[:, 1:-1], atol=1e-5)
    # the new block is live: moving the head's zero weights changes the output
    w = grown.params["head"]["conv"]["w"]
    moved = {**grown.params, "head": {**grown.params["head"], "conv": {**grown.params["head"]["conv"],
                                                                          "w": w + 0.1 * (w == 0)}}}
    assert not np.allclose(apply_model_sequence(moved, grown.state, lr, grown.config, padding="valid"), out_grown)
