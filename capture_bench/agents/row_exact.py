"""A network's forward pass over N rows whose row i is, bit for bit, its forward pass over row i
alone.

torch rounds a row of a batched product by the batch's height: ``layer(x)[i]`` and
``layer(x[i:i + 1])`` differ in their last bits for most rows, because one ``nn.Linear`` row
goes through a matrix-vector kernel and a batch through a matrix-matrix kernel that sums in
another order. A policy evaluated on a batch of episodes would then act differently from the same
policy on each episode alone (its model card's replays, a single env). Every other operation of
the shipped networks (activations, the features extractor's norm, division and logarithm,
clipping) is elementwise or reduces within a row, and gives each row the same numbers whatever
the batch (checked by `capture_bench.agents.sb3_policy.SB3Policy.predict_rows`'s test over
real observations).

So `row_exact_layers` swaps, for the duration of a forward pass, each ``nn.Linear``'s
``forward`` for one that computes N one-row products:

* ``baddbmm`` of N (1 x k) by (k x m) products, where it gives the one-row result (on x86 CPUs,
  the hidden layers);
* else one ``addmv`` per row (the matrix-vector product itself; the small output layers).

Which one a layer takes is decided once per layer by a probe: `PROBE_ROWS` random rows
through both, compared with the layer applied row by row. A kernel that sums in another order
gives other last bits on nearly every row, so a probe that matches on every row has found the
same kernel. A layer neither matches is reported (None), and the caller acts row by row.
"""

from __future__ import annotations

import contextlib
import weakref
from collections.abc import Callable, Iterator
from typing import Any

#: Random rows each layer is probed with.
PROBE_ROWS = 64

Forward = Callable[[Any], Any]
# module -> its nn.Linear layers and their row-exact forwards (None: no batched form matched),
# decided once per module
_LAYERS: weakref.WeakKeyDictionary[Any, tuple[list[Any], list[Forward | None]]] = (
    weakref.WeakKeyDictionary()
)


def _products(layer: Any) -> Forward:
    """``baddbmm``: row i is the (1 x k) by (k x m) product of row i and the weight's transpose."""
    import torch

    weight_t = layer.weight.T

    def forward(x: Any) -> Any:
        n = x.shape[0]
        if layer.bias is None:
            return torch.bmm(x[:, None, :], weight_t.expand(n, -1, -1))[:, 0]
        bias = layer.bias.expand(n, 1, -1)
        return torch.baddbmm(bias, x[:, None, :], weight_t.expand(n, -1, -1))[:, 0]

    return forward


def _matrix_vector(layer: Any) -> Forward:
    """One ``addmv`` (``mv`` without a bias) per row: the weight times the row."""
    import torch

    def forward(x: Any) -> Any:
        if layer.bias is None:
            return torch.stack([torch.mv(layer.weight, row) for row in x])
        return torch.stack([torch.addmv(layer.bias, layer.weight, row) for row in x])

    return forward


def row_exact_forward(layer: Any) -> Forward | None:
    """The first of ``baddbmm`` products and per-row ``addmv`` whose rows equal ``layer``
    applied to each row alone on `PROBE_ROWS` random rows, or None."""
    import torch

    generator = torch.Generator().manual_seed(0)
    probe = torch.randn(PROBE_ROWS, layer.in_features, generator=generator)
    probe = probe.to(layer.weight.dtype)
    chosen = None
    with torch.no_grad():
        alone = torch.cat([layer(probe[i : i + 1]) for i in range(PROBE_ROWS)])
        for make in (_products, _matrix_vector):
            forward = make(layer)
            if torch.equal(forward(probe), alone):
                chosen = forward
                break
    return chosen


@contextlib.contextmanager
def row_exact_layers(module: Any) -> Iterator[bool]:
    """Within the block, every ``nn.Linear`` of ``module`` computes each row of a batch as it
    would alone; yields False (and changes nothing) if some layer has no such form."""
    if module not in _LAYERS:
        import torch

        linear = [m for m in module.modules() if isinstance(m, torch.nn.Linear)]
        _LAYERS[module] = (linear, [row_exact_forward(layer) for layer in linear])
    layers, forwards = _LAYERS[module]
    if any(forward is None for forward in forwards):
        yield False
        return
    for layer, forward in zip(layers, forwards, strict=True):
        # an instance attribute: nn.Module.__call__ finds it before the class's method
        setattr(layer, "forward", forward)  # noqa: B010
    try:
        yield True
    finally:
        for layer in layers:
            del layer.forward
