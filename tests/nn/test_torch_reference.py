"""The PyTorch port used by benchmarks/compare_torch.py computes what `jaxsr.apply_model` computes.

Skipped unless torch is installed (it is not a jaxsr dependency: `pip install torch==2.13.0`). The reference
is `apply_model` itself on random windows of a random model (random BN statistics too), for every layout and
convolution variant of the port and with and without BN folding.
"""


import numpy as np
import pytest

torch = pytest.importorskip("torch")

import torch_reference as tref  # noqa: E402  (benchmarks, pytest's pythonpath)

import jaxsr  # noqa: E402

SMALL = dict(batch=1, lr_shape=(8, 16))


@pytest.mark.parametrize("tr", [0, 4])
def test_port_matches_apply_model(tr):
    errors = tref.check_equivalence([tr], atol=1e-4, **SMALL)
    assert len(errors) == 2 * len(tref.VARIANTS)
    assert max(errors.values()) < 1e-4


def test_port_zero_padding_and_batch():
    """DUF's zero padding of the 5x5 neighbourhoods, and a batch of windows."""
    tref.check_equivalence([0], batch=3, lr_shape=(8, 16), filter_padding="zero", fold_bn=(True,))


def test_check_detects_a_wrong_kernel():
    """A spatially flipped kernel (convolution instead of cross-correlation) is far outside the tolerance."""
    model = tref.random_model(0)
    w = model.params["blocks"][1]["conv2"]["w"]
    params = {**model.params, "blocks": list(model.params["blocks"])}
    params["blocks"][1] = {**params["blocks"][1], "conv2": {**params["blocks"][1]["conv2"], "w": w[:, ::-1, ::-1]}}
    windows = np.random.default_rng(0).uniform(0, 1, (1, 1, 8, 16)).astype(np.float32)
    ref = np.asarray(tref.apply_model_jit(model.params, model.state, windows, model.config))
    flipped = jaxsr.Model(params, model.state, model.config)
    for layout, conv in tref.VARIANTS:
        out = tref.torch_forward(tref.build_torch_net(flipped, layout=layout, conv=conv), windows)
        assert np.max(np.abs(out - ref)) > 1e-3


def test_sequence_matches_super_resolve():
    """Edge-replicated windows and a padded last batch, as `jaxsr.super_resolve`."""
    model = tref.random_model(1)
    lr_seq = np.random.default_rng(1).uniform(0, 1, (5, 8, 16)).astype(np.float32)
    ref = jaxsr.super_resolve(model, lr_seq, batch_size=2)
    out = tref.torch_super_resolve(tref.build_torch_net(model), lr_seq, batch_size=2)
    assert out.shape == (5, 32, 64)
    np.testing.assert_allclose(out, ref, atol=1e-4, rtol=0)
