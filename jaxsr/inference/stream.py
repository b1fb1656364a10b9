"""Live super-resolution in the sequence form: LR frames pushed one at a time, each HR frame R frames later.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..nn.duf import check_conv, sequence_radius
from ..nn.model import Model
from ..nn.streaming import stream_init, stream_step
from ..runtime import compiler_options
from .forms import DEFAULT_PRECISION, check_precision
from .frames import _check_frame, _require_model


@functools.cache
def _stream_step():
    """`stream_step`, jitted once the backend (and so its `compiler_options`) is known."""
    return jax.jit(stream_step, static_argnames=("cfg", "conv3d_impl", "precision"),
                   compiler_options=compiler_options())


class Stream:
    """Live super-resolution in the sequence form: push LR frames one at a time, get each HR frame R frames later.

    `push(frame)` takes an (h, w) LR normalised depth frame and returns the (h r, w r) HR frame of R frames
    earlier (R = 3 + tr, `jaxsr.nn.duf.sequence_radius`), or None during the first R frames; `flush()` ends the
    stream and returns the last min(T, R) HR frames (a list), after which the next `push` starts a new stream.
    The ends are edge-replicated, so the frames equal `super_resolve` of a sequence-form model (and
    `apply_model_sequence`) to float32 rounding. Memory is a fixed set of per-layer buffers (`stream_init`),
    whatever the length of the stream. The weights run in the sequence form whatever `model.config.temporal`
    says (a windowed checkpoint streams too, with the sequence form's accuracy). Outputs are float32 NumPy,
    unclipped. Frames are checked as in `iter_super_resolve` (NaN = no return); raises ValueError for a frame of
    another shape than the first or with values outside [0, 1], and for a flush before any frame.
    precision: how the network's convolutions multiply (`jaxsr.config.PRECISIONS`, default `DEFAULT_PRECISION`),
    checked here.
    """

    def __init__(self, model: Model, *, conv3d_impl: str = "auto", precision: str = DEFAULT_PRECISION):
        self.model = _require_model(model, "Stream")
        if "sequence" not in model.forms:
            raise ValueError(f"Stream: streams the DUF network's sequence form; got a {model.kind} model")
        check_conv(conv3d_impl, check_precision(model, precision, "Stream"), "Stream")
        self.conv3d_impl, self.precision = conv3d_impl, precision
        self.latency = sequence_radius(model.config)
        self._reset()

    def _reset(self):
        self._buffers, self._shape, self._last, self._fed = None, None, None, 0

    def _step(self, frame) -> np.ndarray | None:
        """Feed one padded-sequence frame; the output of step n is frame n - 2R of the sequence."""
        m = self.model
        self._buffers, hr = _stream_step()(m.params, m.state, self._buffers, jnp.asarray(frame)[None], m.config,
                                           conv3d_impl=self.conv3d_impl, precision=self.precision)
        self._fed += 1
        return np.asarray(hr[0]) if self._fed > 2 * self.latency else None

    def push(self, frame) -> np.ndarray | None:
        """Feed LR frame t (h, w); returns HR frame t - R (h r, w r), or None while t < R."""
        frame = _check_frame(frame, self._shape, self._fed - self.latency if self._shape else 0, self.model.channels,
                             who="Stream.push")
        if self._shape is None:  # a new stream: R copies of the first frame before it (edge padding)
            self._shape = frame.shape
            self._buffers = stream_init(self.model.config, frame.shape[:2])
            for _ in range(self.latency):
                self._step(frame)
        self._last = frame
        return self._step(frame)

    def flush(self) -> list[np.ndarray]:
        """End the stream: R copies of the last frame (edge padding) give the HR frames still owed, a list of
        min(T, R) (h r, w r) arrays, T the frames pushed. Raises ValueError if no frame was pushed."""
        if self._shape is None:
            raise ValueError("Stream.flush: no frame was pushed; a stream needs at least one LR frame (h, w)")
        out = [hr for hr in (self._step(self._last) for _ in range(self.latency)) if hr is not None]
        self._reset()
        return out
