"""How each architecture trains, as `fit` asks for it: a `Recipe` per registered architecture.

`fit` is one loop for every network: epochs of jitted steps, validation, early stopping, checkpoints, resume, the
training card and the progress bar. What differs between networks lives here, as five functions of a `Recipe`:
the train state to start from, the jitted step, the default data, the validation set and the validation score.
The DUF network's recipe is in `jaxsr.training.duf`, the learned baselines' in `jaxsr.training.baselines`.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

from ..nn.model import architecture

__all__ = ["Recipe", "recipe", "register_recipe"]


class Recipe(NamedTuple):
    """The training of one architecture.

    init(key, cfg, init) -> train state: a dict of pytrees of arrays with at least "params", "state" (the
    network's) and "opt" (its Adam state); more for networks trained against others (a GAN's discriminator and
    its optimiser). `init` is None (draw the weights from `key`), or a `Model` or checkpoint path to start from.
    step(cfg, train_cfg, make_batch, *, sensor, mesh, conv3d_impl, pretrain_steps) -> run(ts, key, step) ->
    (ts, metrics): one jitted update of the whole train state, data drawn inside from make_batch(key); metrics a dict of
    scalars with at least "loss" (or "g_loss"), "psnr" and "lr". data(cfg, train_cfg, sensor) -> make_batch: the
    default data source. validation(key, cfg, train_cfg, sensor) -> dict of arrays with at least "gt" (N, H, W)
    and, for the bicubic reference, "lr" (N, h, w). evaluate(model, validation, train_cfg, *, sensor,
    conv3d_impl) -> {"loss", "psnr"}: the validation score early stopping reads (lower loss is better).
    data_parallel: whether `step` splits its batch over a mesh's "data" axis; `fit` gives a recipe without it no
    mesh (one device), rather than the same work on every device. published: the config of a learned baseline at
    its published size, which `jaxsr.training.train` (`jaxsr train --arch`) trains; None for the paper's network,
    whose size train's options choose (tr, scale, temporal).
    """

    init: Callable
    step: Callable
    data: Callable
    validation: Callable
    evaluate: Callable
    data_parallel: bool = False
    published: object = None


_RECIPES: dict[str, Recipe] = {}


def register_recipe(name: str, recipe: Recipe) -> Recipe:
    """How architecture `name` (registered with `jaxsr.nn.register_architecture`) trains. Returns `recipe`."""
    architecture(name)  # raises for an unknown architecture
    _RECIPES[name] = recipe
    return recipe


def recipe(cfg) -> Recipe:
    """The `Recipe` of the architecture of `cfg` (a config, a name or a `Model`); ValueError if it has none."""
    arch = architecture(cfg)
    if arch.name not in _RECIPES:
        raise ValueError(f"fit: no training recipe for architecture {arch.name!r}; registered: {', '.join(_RECIPES)}")
    return _RECIPES[arch.name]
