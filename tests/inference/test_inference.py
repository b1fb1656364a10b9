"""Streaming inference: `super_resolve` equals a window-by-window loop of `apply_model`, ends included."""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsr.config import ModelConfig, Sensor
from jaxsr.inference import iter_centre_of_mass, iter_super_resolve, super_resolve, super_resolve_histograms
from jaxsr.nn import Model, apply_model, init_model
from jaxsr.sensor.peaks import centre_of_mass

TINY = dict(base=8, growth=4, head=16, filter_hidden=16)
apply_jit = jax.jit(apply_model, static_argnums=3)


def _model(tr, seed=0):
    cfg = ModelConfig(tr=tr, **TINY)
    return Model(*init_model(jax.random.key(seed), cfg), cfg)


def _loop(model, seq):
    """The reference: one window at a time, indices clipped to the sequence by hand."""
    t_max, tr = seq.shape[0] - 1, model.config.tr
    out = []
    for t in range(seq.shape[0]):
        idx = [min(max(s, 0), t_max) for s in range(t - tr, t + tr + 1)]
        out.append(apply_jit(model.params, model.state, jnp.asarray(seq[idx])[None], model.config)[0])
    return np.stack(out)


@pytest.mark.parametrize("tr,frames,batch", [(0, 5, 1), (1, 7, 3), (2, 3, 2), (2, 9, 4), (1, 1, 8)])
def test_super_resolve_equals_window_loop(tr, frames, batch):
    model = _model(tr)
    seq = np.asarray(jax.random.uniform(jax.random.key(tr + frames), (frames, 4, 6)))
    out = super_resolve(model, seq, batch_size=batch)
    assert out.shape == (frames, 16, 24) and out.dtype == np.float32
    np.testing.assert_allclose(out, _loop(model, seq), rtol=1e-5, atol=1e-6)


def test_conv3d_impl_is_passed_to_the_network():
    """Another way of running the convolutions gives the same frames; an unknown one is refused by name."""
    model = _model(1)
    seq = np.asarray(jax.random.uniform(jax.random.key(5), (4, 4, 6)))
    native = super_resolve(model, seq, batch_size=2, conv3d_impl="native")
    np.testing.assert_allclose(native, _loop(model, seq), rtol=1e-4, atol=1e-5)
    with pytest.raises(ValueError, match="conv3d_impl must be one of"):
        super_resolve(model, seq, batch_size=2, conv3d_impl="fft")


def test_streaming_holds_a_bounded_number_of_frames():
    model = _model(2)
    seq = np.asarray(jax.random.uniform(jax.random.key(3), (12, 4, 6)))
    consumed = []

    def frames():
        for t, f in enumerate(seq):
            consumed.append(t)
            yield f

    stream = iter_super_resolve(model, frames(), batch_size=2)
    first = next(stream)
    # frame 0 needs frames 0..2; with batch 2 the first batch waits for frame 3, and one batch is pending
    assert len(consumed) <= 2 + 2 + 2 * 2
    rest = list(stream)
    np.testing.assert_allclose(np.stack([first] + rest), _loop(model, seq), rtol=1e-5, atol=1e-6)


def test_super_resolve_histograms_is_com_then_super_resolve():
    sensor = Sensor()
    model = _model(1)
    counts = jax.random.poisson(jax.random.key(4), 2.0, (5, 4, 6, sensor.bins)).astype(jnp.float32)
    out = super_resolve_histograms(model, counts, sensor, batch_size=2)
    np.testing.assert_allclose(out, _loop(model, np.asarray(centre_of_mass(counts, sensor))), rtol=1e-5, atol=1e-6)


def test_bad_input_is_refused_clearly():
    model = _model(0)
    with pytest.raises(ValueError, match=r"\(T, h, w\)"):
        super_resolve(model, np.zeros((4, 6)))
    with pytest.raises(ValueError, match="frame 1 has shape"):
        list(iter_super_resolve(model, [np.zeros((4, 6)), np.zeros((4, 7))]))
    with pytest.raises(ValueError, match="batch_size"):
        super_resolve(model, np.zeros((2, 4, 6)), batch_size=0)
    with pytest.raises(ValueError, match="16\\) photon counts"):
        super_resolve_histograms(model, np.zeros((2, 4, 6, 8)))
    with pytest.raises(ValueError, match="negative"):
        list(iter_centre_of_mass(-np.ones((1, 4, 6, 16))))



@pytest.mark.parametrize("make", [lambda s: s * 35.0, lambda s: -s, lambda s: np.where(s == s[0].max(), np.inf, s),
                                  lambda s: np.where(s == s[0].max(), 1.0 + 3e-6, s)],
                         ids=["metres", "negated", "inf", "beyond-the-slack"])
def test_depth_outside_0_1_is_refused_with_the_range_and_the_remedy(make):
    """Metres, negated or infinite input is refused before it reaches the network, naming what was seen and
    how to normalise; the message says how much float slack is allowed."""
    seq = np.asarray(jax.random.uniform(jax.random.key(6), (3, 4, 6)))
    bad = make(seq)
    with pytest.raises(
        ValueError, match=r"frame 0 has values in \[.*\], outside \[0, 1\]: expected normalised depth"
    ) as err:
        super_resolve(_model(0), bad)
    msg = str(err.value)
    assert "--units m" in msg and "jaxsr.normalise_depth" in msg and "1e-06" in msg
    assert f"{np.float32(bad[0].min()):.4g}" in msg


def test_float_slack_is_clipped_and_nan_is_no_return():
    """Within 1e-6 of [0, 1] a value is clipped (rounding, not metres); NaN is "no return", the same as 1.0."""
    model = _model(1)
    seq = np.array(jax.random.uniform(jax.random.key(7), (4, 4, 6)), np.float32)
    seq[0, 0, 0], seq[1, 1, 1] = 0.0, 1.0
    slack = seq.copy()
    slack[0, 0, 0], slack[1, 1, 1] = -9e-7, 1.0 + 9e-7
    np.testing.assert_array_equal(super_resolve(model, slack, batch_size=2), super_resolve(model, seq, batch_size=2))
    holes = seq.copy()
    holes[2, :2] = np.nan
    sky = seq.copy()
    sky[2, :2] = 1.0
    np.testing.assert_array_equal(super_resolve(model, holes, batch_size=2), super_resolve(model, sky, batch_size=2))


_SHARDED_SCRIPT = textwrap.dedent(
    """
    import json
    import jax, numpy as np
    from jaxsr.inference.frames import _batch_sharding, _infer_chunk, super_resolve
    from jaxsr.runtime import use_cpu_cores
    assert use_cpu_cores(n=2) == 2
    assert _batch_sharding(4) is not None and _batch_sharding(3) is None and _batch_sharding(1) is None
    from test_inference import _loop, _model
    model = _model(2)
    seq = np.random.default_rng(3).uniform(0, 1, (7, 8, 12)).astype(np.float32)
    ref = _loop(model, seq)
    errors = {str(b): float(np.max(np.abs(super_resolve(model, seq, batch_size=b) - ref))) for b in (None, 4, 3)}
    compiled = _infer_chunk()._cache_size()
    super_resolve(model, seq)  # the same shapes again: nothing recompiles
    assert _infer_chunk()._cache_size() == compiled == 3, compiled
    print(json.dumps(errors))
    """
)


@pytest.mark.slow  # a subprocess with 4 emulated devices (11 s)
def test_batches_split_over_devices_equal_the_window_loop():
    """Two CPU devices: the default batch (one frame per device) and batch 4 are split over them, batch 3 is
    not; all three equal the one-window-at-a-time reference, the padded last batch included."""
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    env.pop("XLA_FLAGS", None)
    # the script imports test_inference: this folder on its path
    env["PYTHONPATH"] = os.pathsep.join([str(Path(__file__).parent), *filter(None, [env.get("PYTHONPATH")])])
    proc = subprocess.run([sys.executable, "-c", _SHARDED_SCRIPT], capture_output=True, text=True, env=env,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    errors = json.loads(proc.stdout.strip().splitlines()[-1])
    assert max(errors.values()) < 1e-5, errors


def test_the_default_batch_fills_an_accelerator_and_keeps_one_frame_per_cpu_device(monkeypatch):
    from jaxsr.inference import frames as inference

    frames = np.zeros((40, 32, 64), np.float32)
    on_cpu = inference.default_batch_size(frames, sequence_form=False)
    assert on_cpu == inference.DEFAULT_BATCH_SIZE * jax.local_device_count()
    monkeypatch.setattr(inference.jax, "default_backend", lambda: "gpu")
    assert inference.default_batch_size(frames, sequence_form=False) == 8 * jax.local_device_count()
    assert inference.default_batch_size(frames, sequence_form=True) == inference.DEFAULT_SEQUENCE_CHUNK
