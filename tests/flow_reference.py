"""The gradient rules' 3x3 window written plainly, one point at a time: the reference the library's window is held to.

Eq. 19 as docs/method/paper.md states it ("Who is pulled"): a landed point whose landing block is active in
the target is matched and gets nothing; every other landed point gets, per axis, the sum of
``sign(p - T_q)`` over the blocks ``q`` of the 3x3 window around its window centre (the input block
for the paper, the landing block for the centred rules) that are on the grid, active and not its
landing block, ``T_q = (q + 0.5) 2^zoom`` screen pixels, and adds ``|p - T_q|`` (metres at its depth)
to the loss. The reverse side of the two-sided rules pulls every landed point, by the same signs,
towards the blocks of the window around its landing block that are active in the target and hold no
point's projection. Python floats and nested lists here; the library's vectorised window
(:func:`sdm.mapping.flow.block_window`) is held to these loops.
"""
from __future__ import annotations

import math

import torch


def _sign(value: float) -> float:
    return float((value > 0) - (value < 0))


def _pull(screen, depth, landing, target, zoom, camera, pulled):
    """``(flow, loss)`` of the points ``pulled`` ``[(index, config, centre block), ...]`` towards the blocks of
    their window that ``target(config, block)`` lets pull."""
    grid_h, grid_w = target.grid
    size = 1 << zoom
    flow, loss = [[0.0, 0.0] for _ in range(screen.shape[0])], 0.0
    screen_rows, depths, landings = screen.tolist(), depth.tolist(), landing.tolist()
    for i, c, (centre_row, centre_col) in pulled:
        (row, col), (metres_row, metres_col) = screen_rows[i], camera.metres_per_screen_pixel(depths[i])
        for dk in (-1, 0, 1):
            for dl in (-1, 0, 1):
                q = (centre_row + dk, centre_col + dl)
                if not (0 <= q[0] < grid_h and 0 <= q[1] < grid_w) or list(q) == landings[i] or not target(c, q):
                    continue
                off_row, off_col = row - (q[0] + 0.5) * size, col - (q[1] + 0.5) * size
                flow[i][1] += _sign(off_row)  # (row, col) -> (x, y)
                flow[i][0] += _sign(off_col)
                loss += abs(off_row) * metres_row + abs(off_col) * metres_col
    return torch.tensor(flow, dtype=torch.float64), loss


class _Blocks:
    """``target(config, (row, col))``: the block is active (and, given ``skip``, not in it)."""

    def __init__(self, target, skip=frozenset()):
        self.active, self.skip, self.grid = target.tolist(), skip, tuple(target.shape[1:])

    def __call__(self, c, q):
        return bool(self.active[c][q[0]][q[1]]) and (c, *q) not in self.skip


def window_pull(screen, depth, config, landed, centre, landing, target, zoom, camera):
    """Eq. 19 on the window around ``centre``: ``(flow, loss, matched)``, ``(P, 2)`` float64 ``(x, y)``, a float
    (metres), ``(P,)`` bool.

    Arguments as :func:`sdm.mapping.flow.dynamic_flow`'s, with ``centre`` ``(P, 2)`` the window centre blocks.
    """
    blocks = _Blocks(target)
    configs, centres, landings = config.tolist(), centre.tolist(), landing.tolist()
    matched = [bool(is_landed) and blocks(configs[i], landings[i]) for i, is_landed in enumerate(landed.tolist())]
    pulled = [(i, configs[i], centres[i]) for i, is_landed in enumerate(landed.tolist()) if is_landed and not matched[i]]
    flow, loss = _pull(screen, depth, landing, blocks, zoom, camera, pulled)
    return flow, loss, torch.tensor(matched)


def uncovered_pull(screen, depth, config, landed, landing, target, zoom, camera):
    """The two-sided rules' reverse side: ``(flow, loss)`` of every landed point towards the uncovered active blocks
    of the window around its landing block."""
    height, width = camera.screen_shape
    covered = set()
    for (row, col), c in zip(screen.tolist(), config.tolist()):
        pixel = (math.floor(row), math.floor(col))
        if 0 <= pixel[0] < height and 0 <= pixel[1] < width:
            covered.add((c, pixel[0] >> zoom, pixel[1] >> zoom))
    configs, landings = config.tolist(), landing.tolist()
    pulled = [(i, configs[i], landings[i]) for i, is_landed in enumerate(landed.tolist()) if is_landed]
    return _pull(screen, depth, landing, _Blocks(target, covered), zoom, camera, pulled)


def closing_by_max_pools(target, size: int):
    """The morphological closing as two max pools over float32 images (the formulation the product replaced).

    ``(n, h, w)`` bool in and out; dilation pads with -inf (nothing beyond the grid), erosion with 1 (beyond the
    grid counts as active).
    """
    import torch.nn.functional as F

    pad = size // 2
    image = target[:, None].to(torch.float32)
    dilated = F.max_pool2d(image, size, stride=1, padding=pad)
    eroded = -F.max_pool2d(-F.pad(dilated, (pad, pad, pad, pad), value=1.0), size, stride=1)
    return eroded[:, 0] > 0.5


def group_move_recount(screen, depth, config, target):
    """``{(config, depth): [change for y+, y-, x+, x-]}``: the exact zoom-0 mismatch recounted from scratch
    after moving all the points of one configuration with one depth by one pixel (every other point where it
    is). The mismatch: pixels covered by ``floor(screen)`` (on the screen) against the target, false positives
    plus false negatives. Plain Python sets, one group and one move at a time."""
    n, height, width = target.shape
    pixels = [(int(c), math.floor(r), math.floor(q), float(z))
              for (r, q), z, c in zip(screen.tolist(), depth.tolist(), config.tolist())]
    active = {(c, r, q) for c, r, q in target.nonzero().tolist()}

    def mismatch(c, covered):
        on_screen = {(r, q) for r, q in covered if 0 <= r < height and 0 <= q < width}
        held = {(r, q) for cc, r, q in active if cc == c}
        return len(on_screen ^ held)

    changes = {}
    for c, z in sorted({(c, z) for c, _, _, z in pixels}):
        others = [(r, q) for cc, r, q, zz in pixels if cc == c and zz != z]
        own = [(r, q) for cc, r, q, zz in pixels if cc == c and zz == z]
        before = mismatch(c, set(others) | set(own))
        changes[(c, z)] = [mismatch(c, set(others) | {(r + dr, q + dq) for r, q in own}) - before
                           for dr, dq in ((1, 0), (-1, 0), (0, 1), (0, -1))]
    return changes
