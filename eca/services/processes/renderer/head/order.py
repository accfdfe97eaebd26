"""The order the opaque primitives are drawn in: what lies in front first.

Software GL shades a pixel of every primitive that reaches it unless the depth test already rejects it, and
shading (a texture fetch, the light) is most of a frame's cost. Drawn front to back, what is hidden (the scalp
under the hair, eyeballs in their sockets, teeth behind closed lips) fails the depth test before it is shaded.
Which primitive lies in front of which is measured once, at rest, in the full view: each primitive's depth is
drawn alone into a small picture (the drawer does that); where two primitives cover the same pixels, the one
nearer in most of them is in front. The primitives are then put in an order that respects those relations (a
topological order, the larger first among those free to go; a cycle is broken by size).
"""

from __future__ import annotations

import numpy as np

SIZE = (160, 120)  # the depth pictures' size
MIN_SHARED = 8  # pixels two primitives must share for one to count as in front of the other


def in_front(depths: np.ndarray) -> np.ndarray:
    """[a, b]: primitive a lies in front of b, from (P, H, W) depth pictures (1.0 or more where it is absent)."""
    n = len(depths)
    covered = depths < 1.0
    out = np.zeros((n, n), dtype=bool)
    for a in range(n):
        for b in range(a + 1, n):
            shared = covered[a] & covered[b]
            count = int(shared.sum())
            if count < MIN_SHARED:
                continue
            nearer = int((depths[a][shared] < depths[b][shared]).sum())
            if nearer * 2 > count:
                out[a, b] = True
            elif nearer * 2 < count:
                out[b, a] = True
    return out


def front_to_back(depths: np.ndarray, extents: list[float]) -> list[int]:
    """Indices of the primitives whose depth pictures are `depths`, front layers first."""
    before = in_front(depths)
    order: list[int] = []
    left = set(range(len(depths)))
    while left:
        free = [k for k in left if not any(before[j, k] for j in left if j != k)]
        pick = max(free or left, key=lambda k: extents[k])  # in a cycle, the largest goes first
        order.append(pick)
        left.remove(pick)
    return order
