"""The pools' study (experiments/studies/quiet_pools.py) measures the decision the library makes: its default
choice is `jaxsr.inference.iter_quiet`'s flags with P(return) < 1/2, and each choice only moves the flags."""

import numpy as np
import pytest

import quiet_pools  # experiments/studies (pytest's pythonpath)
from jaxsr.config import Sensor
from jaxsr.inference import iter_quiet, lr_blocks


@pytest.mark.slow  # 8-32 s on 2 cores: keeps the default suite under 8 minutes
def test_the_default_choice_is_the_library_decision():
    rng = np.random.default_rng(3)
    counts = rng.poisson(2.0 / 16, (9, 10, 16, 16)).astype(np.float32)
    counts[:, :, :4, 5] += rng.poisson(0.6, (9, 10, 4))  # a dim wall beside sky (120 LR pixels)
    counts[:, 2, 9] = 0.0  # a pixel that sends back nothing amid the sky
    raw = rng.uniform(0.1, 0.9, (9, 40, 64)).astype(np.float32)
    p = rng.uniform(0.0, 1.0, (9, 40, 64)).astype(np.float32)
    (choice,) = [v for k, v in quiet_pools.CHOICES.items() if "the default" in k]
    got = quiet_pools.decided(raw, p, counts, *choice)
    quiet = lr_blocks(np.stack(list(iter_quiet(iter(counts), Sensor(), alpha=1e-3))), 4)
    np.testing.assert_array_equal(got, np.where(quiet & (p < 0.5), np.float32(1.0), raw))
    pools = choice[0]
    pooled = quiet_pools.decided(raw, p, counts, pools, None, None)
    alone = quiet_pools.decided(raw, p, counts, (), None, None)
    assert (alone == 1.0).sum() >= (pooled == 1.0).sum()  # pooling only ever keeps more depth
    sky = quiet_pools.decided(raw, p, counts, pools, 64, 64)
    assert ((sky == 1.0) & (got != 1.0)).any()  # beside the sky, P(return) decides the wall's HR pixels
