"""Train steps of the learned baselines (HistNet, iSeeBetter) and the data source HistNet needs.

- iSeeBetter takes LR depth windows like our network: `jaxsr.data.scene_batches(tr=cfg.frames // 2, train_cfg)`
  (or `sequence_batches`) feeds `make_iseebetter_train_step` as it is.
- HistNet takes the LR photon histograms and the HR intensity of one frame: `histogram_batches` renders
  `jaxsr.scenes.training_clip` scenes (one frame), simulates histograms with the same SNR / mean-signal ranges and
  crops as `scene_batches`, and returns (counts, HR intensity, HR normalised depth).

Each step is one jitted function: data simulated inside it, forward, loss, gradients, `jaxsr.optim.adam_update`
with lr = schedule(step) (iSeeBetter / RBPN: Adam lr 1e-4, /10 at half the epochs; HistNet's code: Adam or
proximal Adagrad, L1 loss).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .config import SensorConfig, TrainConfig
from .data import log_uniform
from .histnet import HistNetConfig, apply_histnet
from .metrics import psnr
from .optim import adam_init, adam_update
from .rbpn import RBPNConfig, apply_discriminator, apply_rbpn, discriminator_loss, generator_loss
from .scenes import training_clip
from .sensor import normalise_depth, simulate_histograms

__all__ = ["histogram_batches", "make_histnet_train_step", "make_iseebetter_train_step", "init_adam_pair"]
_SENSOR = SensorConfig()  # the default sensor


def _crop(key, counts, intensity, gt, patch, scale):
    """The same random LR crop of counts (h, w, K) and of the HR intensity and depth (h r, w r)."""
    if patch is None:
        return counts, intensity, gt
    ph, pw = patch
    h, w, k = counts.shape
    if ph > h or pw > w or ph % 4 or pw % 4:
        raise ValueError(f"histogram_batches: patch {patch} must fit the LR frame {(h, w)} and be divisible by 4")
    ky, kx = jax.random.split(key)
    y0 = jax.random.randint(ky, (), 0, h - ph + 1)
    x0 = jax.random.randint(kx, (), 0, w - pw + 1)
    counts = jax.lax.dynamic_slice(counts, (y0, x0, 0), (ph, pw, k))
    hr = lambda a: jax.lax.dynamic_slice(a, (y0 * scale, x0 * scale), (ph * scale, pw * scale))
    return counts, hr(intensity), hr(gt)


def histogram_batches(train_cfg: TrainConfig, *, sensor: SensorConfig = _SENSOR):
    """HistNet's data source: `make_batch(key)` with `batch_size` random single-frame scenes.

    Per example: `jaxsr.scenes.training_clip` (1 frame) -> SNR and mean signal log-uniform in the config's ranges
    -> `simulate_histograms`; an optional random crop (`patch`, LR pixels, divisible by 4). Returns make_batch:
    key -> (counts (B, h, w, K), intensity (B, h r, w r) rendered HR intensity in [0, 1], gt (B, h r, w r) HR
    normalised depth).
    """
    def example(key):
        k_scene, k_snr, k_sig, k_noise, k_crop = jax.random.split(key, 5)
        depth, intensity = training_clip(k_scene, 1, sensor=sensor, shift_range=train_cfg.motion_range)
        snr = log_uniform(k_snr, *train_cfg.snr_range)
        mean_signal = log_uniform(k_sig, *train_cfg.mean_signal_range)
        counts = simulate_histograms(k_noise, depth, intensity, sensor, snr=snr, mean_signal=mean_signal)
        return _crop(k_crop, counts[0], intensity[0], normalise_depth(depth, sensor)[0], train_cfg.patch, sensor.scale)

    def make_batch(key):
        return jax.vmap(example)(jax.random.split(key, train_cfg.batch_size))

    make_batch.description = "jaxsr.scenes.training_clip (1 frame) -> simulate_histograms; rendered HR intensity"
    return make_batch


def make_histnet_train_step(cfg: HistNetConfig, make_batch, *, schedule, sensor: SensorConfig = _SENSOR):
    """The jitted HistNet train step: step(params, opt_state, key, step) -> (params, opt_state, metrics).

    make_batch: key -> (counts (B, h, w, K), intensity (B, H, W), gt (B, H, W)), e.g. `histogram_batches`;
    schedule: step -> lr (e.g. `jaxsr.step_decay(1e-4, factor=0.1, every=...)`). Loss: mean |hr - gt| (the
    published code's L1). Returns the step; metrics {"loss", "psnr" (prediction clipped to [0, 1]), "lr"}.
    """
    def step_fn(params, opt_state, key, step):
        counts, intensity, gt = make_batch(key)

        def loss_fn(p):
            hr = apply_histnet(p, counts, intensity, cfg, sensor=sensor)
            return jnp.mean(jnp.abs(hr - gt)), hr

        (loss, hr), grads = jax.value_and_grad(loss_fn, has_aux=True)(params)
        lr = schedule(step)
        params, opt_state = adam_update(grads, opt_state, params, lr=lr, eps=1e-8)
        return params, opt_state, {"loss": loss, "psnr": jnp.mean(psnr(jnp.clip(hr, 0, 1), gt)), "lr": lr}

    return jax.jit(step_fn, donate_argnums=(0, 1))


def init_adam_pair(g_params, d_params):
    """Adam states of the generator and the discriminator, for `make_iseebetter_train_step`.

    g_params, d_params: pytrees of arrays of any shape. Returns (AdamState of g_params, AdamState of d_params).
    """
    return adam_init(g_params), adam_init(d_params)


def make_iseebetter_train_step(cfg: RBPNConfig, make_batch, *, schedule, adversarial: float = 1e-3,
                               tv: float = 2e-8, charbonnier: bool = False):
    """The jitted iSeeBetter train step (one discriminator update, then one generator update, as iSeeBetter).

    step((g_params, d_params, d_state), (g_opt, d_opt), key, step) -> (same, same, metrics).
    make_batch: key -> (windows (B, frames, h, w), gt (B, h r, w r)), e.g. `jaxsr.data.scene_batches(cfg.frames //
    2, train_cfg)`; the flows are computed once per batch (`rbpn_flows`). schedule: step -> lr for both.
    Losses: `discriminator_loss`, `generator_loss` (MSE + adversarial + tv; no VGG term). Returns the step;
    metrics {"d_loss", "g_loss", "content", "adversarial", "psnr", "lr"}.
    """
    def step_fn(nets, opts, key, step):
        g_params, d_params, d_state = nets
        g_opt, d_opt = opts
        windows, gt = make_batch(key)
        lr = schedule(step)
        # one generator forward pass serves both updates; its pullback gives the generator's gradient
        hr, pullback = jax.vjp(lambda gp: apply_rbpn(gp, windows, cfg), g_params)

        def d_loss_fn(dp):
            real, st = apply_discriminator(dp, d_state, gt, cfg, train=True)
            fake, st = apply_discriminator(dp, st, hr, cfg, train=True)
            return discriminator_loss(real, fake), st

        (d_loss, d_state), d_grads = jax.value_and_grad(d_loss_fn, has_aux=True)(d_params)
        d_params, d_opt = adam_update(d_grads, d_opt, d_params, lr=lr, eps=1e-8)

        def g_loss_fn(out):  # against the updated discriminator, as iSeeBetter's trainer
            fake, _ = apply_discriminator(d_params, d_state, out, cfg, train=True)
            loss, parts = generator_loss(out, gt, fake, adversarial=adversarial, tv=tv, charbonnier=charbonnier)
            return loss, parts

        (g_loss, parts), d_hr = jax.value_and_grad(g_loss_fn, has_aux=True)(hr)
        (g_grads,) = pullback(d_hr)
        g_params, g_opt = adam_update(g_grads, g_opt, g_params, lr=lr, eps=1e-8)
        out = hr
        metrics = {"d_loss": d_loss, "g_loss": g_loss, "content": parts["content"],
                   "adversarial": parts["adversarial"], "psnr": jnp.mean(psnr(jnp.clip(out, 0, 1), gt)), "lr": lr}
        return (g_params, d_params, d_state), (g_opt, d_opt), metrics

    return jax.jit(step_fn, donate_argnums=(0, 1))
