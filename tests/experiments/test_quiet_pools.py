"""The pools' study (experiments/studies/quiet_pools.py) measures the decision the library makes: its default
choice is `jaxsr.inference.iter_quiet`'s flags with P(return) < 1/2 and its black holes filled
(`filled_where_holes`), and each choice only moves the flags or the holes' depth."""

import numpy as np
import pytest

import quiet_pools  # experiments/studies (pytest's pythonpath)
from jaxsr.config import DepthScale, Sensor
from jaxsr.inference import filled_where_holes, iter_quiet, lr_blocks


@pytest.mark.slow  # 8-32 s on 2 cores: keeps the default suite under 8 minutes
def test_the_default_choice_is_the_library_decision():
    rng = np.random.default_rng(3)
    counts = rng.poisson(2.0 / 16, (9, 10, 16, 16)).astype(np.float32)
    counts[:, :, :4, 5] += rng.poisson(0.6, (9, 10, 4))  # a dim wall beside sky (120 LR pixels)
    counts[:, 2, 9] = 0.0  # a pixel that sends back nothing amid the sky
    counts[:, 3:9, 8:14, 7] += rng.poisson(6.0, (9, 6, 6))  # a bright surface amid the sky ...
    counts[:, 5:7, 10:12] = 0.0  # ... with a black patch that it encloses: a hole
    raw = rng.uniform(0.1, 0.9, (9, 40, 64)).astype(np.float32)
    p = rng.uniform(0.0, 1.0, (9, 40, 64)).astype(np.float32)
    (choice,) = [v for k, v in quiet_pools.CHOICES.items() if "the default" in k]
    got = quiet_pools.decided(raw, p, counts, *choice)
    flags = list(iter_quiet(iter(counts), Sensor(), alpha=1e-3))
    quiet = lr_blocks(np.stack([q.quiet for q in flags]), 4)
    assert np.stack([q.black for q in flags])[:, 5:7, 10:12].all()
    decided = np.where(quiet & (p < 0.5), np.float32(1.0), raw)
    want = np.stack([filled_where_holes(d, q.black, DepthScale()) for d, q in zip(decided, flags)])
    np.testing.assert_array_equal(got, want)
    pools, max_hole = choice[:2]
    network = quiet_pools.decided(raw, p, counts, pools, max_hole, None)  # the holes left to the network's depth
    np.testing.assert_array_equal(network, decided)
    in_depth = quiet_pools.decided(raw, p, counts, pools, max_hole, None, "depth")
    hole = lr_blocks(np.stack([q.black for q in flags]), 4)
    assert not np.array_equal(in_depth[hole], got[hole]) and np.array_equal(in_depth[~hole], got[~hole])
    with pytest.raises(ValueError, match="fill"):
        quiet_pools.decided(raw, p, counts, pools, max_hole, None, "nearest")
    pooled = quiet_pools.decided(raw, p, counts, pools, None, None)
    alone = quiet_pools.decided(raw, p, counts, (), None, None)
    assert (alone == 1.0).sum() >= (pooled == 1.0).sum()  # pooling only ever keeps more depth
    sky = quiet_pools.decided(raw, p, counts, pools, 64, 64)
    assert ((sky == 1.0) & (got != 1.0)).any()  # beside the sky, P(return) decides the wall's HR pixels
