"""Copies agree: the ordered product's instances in a bin look like each other, a look-alike of
another product looks like few of them (the thesis's repeated-object view, ch. 5).

The product check compares each detection with the shop photo only. A same-coloured other product
(a green shape beside green-and-white cylinders, a yellow box beside a yellow toy) passes it at 0.95
while the real copies score 0.99, and the detector's own score can put the look-alike first. Asked
of the detections themselves, window against window, the check finds the copies agreeing with each
other (0.99) and the look-alike with none of them (0.80). A detection's *support* is the most any
other detection agrees with it, weighted by how sure the check is that the other one is the ordered
product (a look-alike's twin that is not the product lends no support); the ranking multiplies the
detector's score and the check's by support to a power.

What it assumes: the ordered product is the one repeated in the bin, as in the bins it was measured
on (3-6 copies beside 2-3 single other products). Where the product lies alone beside two copies of a
look-alike that the check also passes (0.99 against 0.95), the look-alikes back each other and the lone
copy loses its lead; ``Picker(agreement=None)`` ranks by detector and check alone.
"""

from __future__ import annotations

import numpy as np

POWER = 4.0  # support ** POWER in the ranking (measured: docs/notes.md, "Tuning notes")
WINDOWS = 8  # the best-ranked detections compared with each other (the rest keep their places after them)


def support(pairwise: np.ndarray, same: np.ndarray) -> np.ndarray:
    """Each detection's support from the others: ``max_j pairwise[i, j] * same[j]`` over ``j != i``
    (``pairwise``: (n, n) P(same product) between detections; ``same``: (n,) the product check's
    P(the ordered product) of each). 1 for a detection alone."""
    pairwise, same = np.asarray(pairwise, dtype=float), np.asarray(same, dtype=float)
    n = len(same)
    if n < 2:
        return np.ones(n)
    weighted = pairwise * same[None, :]
    np.fill_diagonal(weighted, -np.inf)
    return np.clip(weighted.max(1), 0.0, 1.0)


def rank_by_support(ranked: list, pairwise_of, power: float = POWER, windows: int = WINDOWS) -> list:
    """``ranked``: (box, detector score, check score) best first. The first ``windows`` of them
    re-ranked by detector score x check score x support ** ``power`` (``pairwise_of(boxes)`` -> their
    (n, n) agreement); the rest after them in their order. Unchanged where fewer than two were checked."""
    head, tail = ranked[:windows], ranked[windows:]
    if len(head) < 2 or any(same is None for _, _, same in head):
        return list(ranked)
    boxes = np.array([box for box, _, _ in head], dtype=float).reshape(-1, 4)
    backing = support(pairwise_of(boxes), np.array([same for _, _, same in head], dtype=float))
    keys = [-score * same * backing[i] ** power for i, (_, score, same) in enumerate(head)]
    return [head[i] for i in np.argsort(keys, kind="stable")] + tail
