"""The communication graph laid out for the page: columns by hops from the leader, no label on
another's.

``graph_layout`` places the leader (node 0) in the first column and each follower in the column of
its hop count (the fewest edges from the leader along the directed graph; a follower no path
reaches goes in a last column of its own). A column with more nodes than fit one above the other
at ``ROW_PX`` is split into sub-columns side by side, and within a column the nodes are ordered by
the mean row of their in-neighbours in the columns before (fewer crossing edges; ties by id). Each
node is drawn as a disc of ``NODE_PX`` with its id inside, so two nodes overlap only if their
centres are closer than ``NODE_PX`` in both directions: ``tests/test_view.py`` holds every
generated graph up to 64 followers to that at the page's default size.
"""

import math
from collections import deque

NODE_PX = 16  #: a node's disc and its label: a box this wide and high [px]
ROW_PX = 20  #: the least distance between two nodes' centres in a column [px]
MARGIN_PX = 14  #: from the canvas's edge to the nearest centre [px]


def hops_from_leader(n_followers: int, edges: list[tuple[int, int]]) -> dict[int, int | None]:
    """Each node's fewest edges from node 0 along ``edges`` (None: no path reaches it)."""
    outs: dict[int, list[int]] = {}
    for s, d in edges:
        outs.setdefault(s, []).append(d)
    hops: dict[int, int | None] = dict.fromkeys(range(n_followers + 1))
    hops[0] = 0
    todo = deque([0])
    while todo:
        s = todo.popleft()
        h = hops[s]
        assert h is not None  # (only reached nodes are queued)
        for d in outs.get(s, []):
            if hops[d] is None:
                hops[d] = h + 1
                todo.append(d)
    return hops


def graph_layout(
    n_followers: int, edges: list[tuple[int, int]], width_px: float, height_px: float
) -> dict[int, tuple[float, float]]:
    """Each node's centre on a canvas of ``width_px`` x ``height_px`` [px, y down]. Columns that
    do not fit side by side at ``ROW_PX`` apart (a deep graph: a ring of 64 is 65 hops long) are
    folded into bands, one below the other, the hops running on from band to band."""
    hops = hops_from_leader(n_followers, edges)
    deepest = max((h for h in hops.values() if h is not None), default=0)
    by_hop: list[list[int]] = [[] for _ in range(deepest + 2)]
    for node, h in sorted(hops.items()):
        by_hop[deepest + 1 if h is None else h].append(node)
    columns = [c for c in by_hop if c]
    ins: dict[int, list[int]] = {}
    for s, d in edges:
        ins.setdefault(d, []).append(s)
    inner_w, inner_h = width_px - 2 * MARGIN_PX, height_px - 2 * MARGIN_PX
    fit_across = max(1, int(inner_w // ROW_PX) + 1)
    bands = 1
    while True:
        band_h = (inner_h - (bands - 1) * ROW_PX) / bands  # (a row's gap between two bands)
        subcolumns = _subcolumns(columns, ins, max(1, int(band_h // ROW_PX) + 1))
        if math.ceil(len(subcolumns) / bands) <= fit_across or band_h < ROW_PX:
            break
        bands += 1
    per_band = math.ceil(len(subcolumns) / bands)
    out: dict[int, tuple[float, float]] = {}
    for c, part in enumerate(subcolumns):
        band, c_in = divmod(c, per_band)
        n_across = min(per_band, len(subcolumns) - band * per_band)
        x = MARGIN_PX + (inner_w * c_in / (n_across - 1) if n_across > 1 else inner_w / 2)
        top = MARGIN_PX + band * (band_h + ROW_PX)
        for r, node in enumerate(part):
            y = top + (band_h * r / (len(part) - 1) if len(part) > 1 else band_h / 2)
            out[node] = (round(x, 1), round(y, 1))
    return out


def _subcolumns(columns: list[list[int]], ins: dict[int, list[int]], per_column: int) -> list[list[int]]:
    """``columns`` (by hop) split into parts of at most ``per_column``, each ordered by the mean
    place of its nodes' in-neighbours in the parts before (ties by id)."""
    row: dict[int, float] = {}  # each placed node's place in its part, 0..1
    out: list[list[int]] = []
    for col in columns:

        def key(node: int) -> tuple[float, int]:
            parents = [row[p] for p in ins.get(node, []) if p in row]
            return (sum(parents) / len(parents) if parents else 0.5, node)

        ordered = sorted(col, key=key)
        k = math.ceil(len(ordered) / per_column)
        size = math.ceil(len(ordered) / k)
        for j in range(k):
            part = ordered[j * size : (j + 1) * size]
            out.append(part)
            for r, node in enumerate(part):
                row[node] = (r + 0.5) / len(part)
    return out
