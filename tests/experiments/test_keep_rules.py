"""experiments/studies/keep_rules.py: each rule's decision on hand-made head outputs, and the blocks' signal."""

import numpy as np

import jaxsr
import keep_rules  # experiments/studies (pytest's pythonpath)


def test_rules_decide_as_described():
    """Four 4 x 4 blocks: (0, 0) dropped whole, confident, bright; (0, 1) half dropped, confident; (1, 0) dropped
    whole, barely, its photons passing for ambient light; (1, 1) kept."""
    depth = np.full((1, 8, 8), 0.3, np.float32)
    logit = np.full((1, 8, 8), -5.0, np.float32)
    logit[0, :4, :4] = 5.0
    logit[0, :4, 4:6] = 5.0
    logit[0, 4:, :4] = 1.0
    quiet = np.array([[[False, False], [True, False]]])
    signal = np.array([[[40.0, 5.0], [0.0, 5.0]]])
    out = keep_rules.rules(depth, logit, quiet, signal, 0.0)
    dropped = {name: (sr[0] == 1.0) for name, sr in out.items()}

    def blocks(*cells, half=False):
        m = np.zeros((8, 8), bool)
        for y, x in cells:
            m[4 * y:4 * y + 4, 4 * x:4 * x + 4] = True
        if half:
            m[:4, 4:6] = True
        return m

    np.testing.assert_array_equal(dropped["head"], blocks((0, 0), (1, 0), half=True))
    np.testing.assert_array_equal(dropped["keep"], blocks((1, 0)))  # only where the photons pass for ambient
    np.testing.assert_array_equal(dropped["whole blocks"], blocks((1, 0), half=True))
    for s in keep_rules.SIGNALS:  # 40 photons a frame in (0, 0): the head stands there
        np.testing.assert_array_equal(dropped[f"signal >= {s:g}"], blocks((0, 0), (1, 0)))
    for d in keep_rules.MARGINS:  # logit 5 clears 0 + 2 and 0 + 4; (1, 0) stands as quiet
        np.testing.assert_array_equal(dropped[f"+{d:g} where a return"], blocks((0, 0), (1, 0), half=True))
    # where no return is not decided, the network's depth
    for sr in out.values():
        np.testing.assert_array_equal(sr[0][sr[0] != 1.0], np.float32(0.3))


def test_block_signal_per_frame_over_a_short_sequence():
    """A return of 4 photons a frame in one pixel, no ambient light, 3 frames (fewer than the 9 summed): 4 signal
    photons per frame there, none elsewhere."""
    counts = np.zeros((3, 4, 4, 16), np.float32)
    counts[:, 1, 2, 5] = 4.0
    signal = keep_rules.block_signal(counts, jaxsr.SensorConfig())
    assert signal.shape == (3, 4, 4)
    np.testing.assert_allclose(signal[:, 1, 2], 4.0, rtol=1e-5)
    signal[:, 1, 2] = 0.0
    np.testing.assert_allclose(signal, 0.0, atol=1e-6)
