"""The exact zoom-0 pixel loss that CMA-ES minimises (:mod:`sdm.experiments.baselines.cmaes`), counted fast and exactly.

How it is counted (:class:`PixelMismatch`, :class:`ShiftLayout`). The screen position of a point is
affine in ``theta``: ``row = row_0 + b g_r``, ``col = col_0 + a g_c`` with gains ``g = f' / z`` that
depend on the depth alone. All points of one configuration with the same depth (a car's disc in
``E'``) and the same sub-pixel offset therefore move by the *same whole number of pixels*; each
pixel holds one point at ``theta = 0``, so such a group never covers a pixel twice. Points are
grouped once per set (configuration, depth, sub-pixel offset, 16 x 16 tile); an evaluation then
computes one integer shift per group (~11k groups instead of ~274k points on the default data),
the points' flat pixel ids by a cumulative sum, and

    mismatch = |target| + sum over the distinct rendered pixels of w,   w = +1 off target, -1 on target

over the screen padded by 16 pixels (``w = 0`` in the margin, where the points of a group that
leave the screen land: a group entirely off screen is clamped into the margin). Pixels covered
twice (two groups of one configuration overlapping after the shift: common, the discs of ``E'``
touch) are counted once: every point writes its group's number within its configuration to its
pixel's entry, and only the point that reads its own number back counts. ``w + 1`` and that
number share one int16 entry per padded pixel (one cache line for the write and the read: an
evaluation is bound by memory latency). Nothing of size ``N x H x W`` is zeroed or counted per
evaluation: on the default data an evaluation inside a search costs a fifth to a sixth of the
count of a whole N x H x W bitmap per evaluation (2.0-2.8 ms against 12.2 ms, one thread;
benchmarks/speed/bench_cmaes.py).

Compiled (:func:`sdm.experiments.baselines.cmaes_native.pixel_mismatch`, ``sdm_pixel_mismatch`` in ``kernel/mismatch.c``): the
same groups, the same float operations for each group's shift and its trust check, then one loop
over the points per candidate, configuration by configuration with the whole generation (pycma's
6 candidates) in one call, so a configuration's pixels stay in cache across its candidates; a
pixel covered twice is told by a stamp per padded pixel of one configuration. It remembers its last
candidates (:class:`MismatchMemo`): a configuration whose groups all shift as in one of them takes
that sum instead of a pass over its points (a configuration's count depends on its groups' whole
shifts alone, and near convergence most candidates shift most configurations alike). The counts are
the torch count's integers (tests/baselines/test_baselines_cmaes.py holds both paths to the straightforward
count and to each other). On the default data a search costs 0.39 CPU ms per evaluation against
the torch count's 1.04 (pycma and the per-run set-up included; 0.097 against 0.257 s per run, one
thread, 10 runs at level 2: benchmarks/speed/bench_cmaes.py, 2026-12-03). Where the kernel is not available (no C
compiler, ``SDM_NATIVE=0``, CUDA tensors) the torch count runs, one candidate at a time.

Exactness: the shared shift equals each point's own ``floor`` (as computed by
:meth:`PixelMismatch.reference`, the point-by-point count) unless ``frac(row_0) + b g_r`` lies
within ``1e-7`` pixel of an integer for some group (the float rounding of both computations is
below ``1e-9`` pixel for coordinates and shifts under ``1e6`` pixels). Such a candidate (and any
beyond ``1e6`` pixels) is counted by :meth:`PixelMismatch.reference`: the fast count is the
reference count for every ``theta``, not an approximation. On the default data the fallback is
taken about once in 450 evaluations (9 of 4000 random thetas).
"""
from __future__ import annotations

import math
import sys

import torch

from ...batch import ConfigurationSet
from ...camera import Camera
from ...mapping.build import serves
from .cmaes_native import pixel_mismatch


#: Groups are cut into tiles of this many screen pixels a side, so a group spans at most
#: ``TILE - 1`` rows and columns, and the screen is padded by ``TILE`` pixels on every side: a
#: group clamped to lie just off screen still fits in the margin.
TILE = 16
#: A group's shared shift is trusted when every point's ``frac + shift`` is at least this far
#: (screen pixels) from an integer; the float rounding involved is below 1e-9 pixel.
EXACT_MARGIN = 1e-7
#: Coordinates and shifts (screen pixels) up to which that rounding bound holds.
EXACT_RANGE = 1e6


def _projection(points: torch.Tensor, camera: Camera) -> tuple[torch.Tensor, torch.Tensor]:
    """``(origin, gain)``: ``(P, 2)`` float64 screen ``(row, col)`` at ``theta = 0`` and pixels per metre of ``(b, a)``.

    The projection is affine in theta for a fixed depth: row = row_0 + b fy' / z, col = col_0 + a fx' / z
    (fy', fx': focal lengths in screen pixels). Precomputing row_0, col_0 and the two gains makes an
    evaluation two multiply-adds per point instead of a projection; it agrees with
    camera.project(Q + (a, b, 0)) to ~1e-13 pixel, so a floor can differ only for a point within
    that distance of a pixel border.
    """
    origin = camera.project(points)
    gain = torch.stack((camera.fy * camera.rows_per_image_pixel / points[:, 2],
                        camera.fx * camera.cols_per_image_pixel / points[:, 2]), dim=1)
    return origin, gain


def _groups(points: torch.Tensor, config: torch.Tensor, frac: torch.Tensor, whole: torch.Tensor,
            n_configs: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``(order, starts)``: the points sorted into rigidly moving groups, ``(P,)`` int64 the set's point index
    of each point in group order and ``(P,)`` bool where a group starts.

    A group shares its configuration, its sub-pixel offset (to 1/1024 pixel; the exactness check uses the
    real spread), its ``TILE`` x ``TILE`` tile and its depth (bit pattern: equal depth, equal gains). Sorted by
    stable argsorts, least significant key first, instead of ``torch.unique(dim=0)``, which is 10x slower here.

    Args: ``points`` ``(P, 3)`` float64 metres; ``config`` ``(P,)`` int64 each point's configuration;
    ``frac`` ``(P, 2)`` float64 and ``whole`` ``(P, 2)`` int64 its sub-pixel and whole screen ``(row, col)``;
    ``n_configs`` ``N``.
    """
    fine = torch.round(frac * 1024).to(torch.int64)  # 0..1024
    tiles = torch.div(whole, TILE, rounding_mode="floor")
    tiles = tiles - tiles.min(0).values
    tile_span = (tiles.max(0).values + 1).tolist()
    keys = [((fine[:, 0] * 1025 + fine[:, 1]) * tile_span[0] + tiles[:, 0]) * tile_span[1] + tiles[:, 1]]
    if n_configs * 1025**2 * tile_span[0] * tile_span[1] < 2**62:
        keys[0] = keys[0] + config * (1025**2 * tile_span[0] * tile_span[1])  # configuration-major
    else:
        keys.append(config)
    keys.insert(0, points[:, 2].contiguous().view(torch.int64))
    order = torch.arange(points.shape[0], device=points.device)
    for key in keys:
        order = order[torch.argsort(key[order], stable=True)]
    keys = [key[order] for key in keys]
    starts = torch.zeros(order.numel(), dtype=torch.bool, device=points.device)
    starts[0] = True
    for key in keys:
        starts[1:] |= key[1:] != key[:-1]
    return order, starts


class ShiftLayout:
    """The points of a set grouped into rigidly moving blocks, and the scratch tensors of an evaluation.

    Depends on the points, the configuration offsets and the camera only, not on the targets: the
    runs of :func:`fit_runs` (same points, different noisy targets) share one layout. Not safe to
    use from two threads at once (the scratch tensors are reused).

    Args:
        train_set: the configurations (its targets are ignored).
        camera: camera and screen; default the set's own.

    Attributes (G groups, P points, in group order):
        order: ``(P,)`` int64 the set's point index of each point.
        padded_shape: ``(Hp, Wp)`` the padded screen, ``H + 2 TILE`` by ``W + 2 TILE``.
        codes: ``(P,)`` int8/int16/int32 each point's group number within its configuration.
    """

    def __init__(self, train_set: ConfigurationSet, camera: Camera | None = None) -> None:
        self.camera = camera or train_set.camera
        points = train_set.points
        self._points, self._counts, self._reference, self._stamp = points, train_set.counts, None, None
        device = points.device
        n_configs = len(train_set)
        origin, gain = _projection(points, self.camera)
        self.usable = bool(points.shape[0] > 0) and bool(origin.abs().max() <= EXACT_RANGE)
        if not self.usable:  # far off-screen points (not in Sky sets): PixelMismatch counts by reference
            return
        config = torch.repeat_interleave(torch.arange(n_configs, device=device), train_set.counts)
        whole = torch.floor(origin)
        frac = origin - whole  # exact for origin >= 0, within 1e-16 below 0: far inside EXACT_MARGIN
        whole = whole.to(torch.int64)
        self.order, starts = _groups(points, config, frac, whole, n_configs)
        config = config[self.order]
        group = torch.cumsum(starts, 0) - 1  # (P,) group of each point, groups in configuration order
        gain, frac, whole = gain[self.order], frac[self.order], whole[self.order]
        first = starts.nonzero().squeeze(1)  # (G,) first point of each group
        self._shift_bounds(group, gain[first], frac, whole)
        local = self._pixels(config, whole, first, n_configs)
        most = int(local.max()) + 1
        if most > 32767:  # not a screen's worth of groups in one configuration
            self.usable = False
            return
        # A padded pixel's table entry holds two halves: the low one its weight + 1 (per run), the
        # high one the code of the last group that wrote there (per evaluation). One entry, one cache
        # line for the write and both reads: the evaluation is bound by memory traffic.
        self.half_dtype, self.table_dtype, self.half_bits = (
            (torch.int8, torch.int16, 8) if most <= 127 else (torch.int16, torch.int32, 16))
        self.codes = local[group].to(self.half_dtype)  # (P,) group number within its configuration
        self.codes_high = self.codes.to(self.table_dtype) << self.half_bits  # (P,) the code as a table entry's high half
        self.ids = torch.empty(self.order.numel(), dtype=torch.int64, device=device)

    def _shift_bounds(self, group: torch.Tensor, gain: torch.Tensor, frac: torch.Tensor,
                      whole: torch.Tensor) -> None:
        """Each group's gains, sub-pixel spread and the range its whole shift is clamped to.

        Args (P points in group order, G groups): ``group`` ``(P,)`` int64; ``gain`` ``(G, 2)`` float64 pixels
        per metre (one depth per group); ``frac`` ``(P, 2)`` float64 and ``whole`` ``(P, 2)`` int64 the
        points' sub-pixel and whole screen ``(row, col)`` at ``theta = 0``.
        """
        n_groups, device = gain.shape[0], gain.device

        def reduce(values: torch.Tensor, how: str) -> torch.Tensor:
            fill = math.inf if how == "amin" else -math.inf
            if not values.is_floating_point():
                fill = 2**62 if how == "amin" else -(2**62)
            out = torch.full((n_groups,), fill, dtype=values.dtype, device=device)
            return out.scatter_reduce_(0, group, values, how)

        height, width = self.camera.screen_shape
        self.gain = gain  # (G, 2) float64, one depth per group
        self.frac_low = torch.stack((reduce(frac[:, 0], "amin"), reduce(frac[:, 1], "amin")), 1)  # (G, 2)
        self.frac_high = torch.stack((reduce(frac[:, 0], "amax"), reduce(frac[:, 1], "amax")), 1)
        whole_low = torch.stack((reduce(whole[:, 0], "amin"), reduce(whole[:, 1], "amin")), 1)
        whole_high = torch.stack((reduce(whole[:, 0], "amax"), reduce(whole[:, 1], "amax")), 1)
        self.max_gain = self.gain.abs().max(0).values.tolist()  # [rows, cols] per metre
        # Clamp range of a group's shift: the group stays inside the padded screen; a shift that
        # is clamped had put the whole group off screen, and the clamped one still does (span < TILE).
        screen = torch.tensor([height, width], dtype=torch.int64, device=device)
        # floor(frac_low - margin + shift) == floor(frac_high + margin + shift): one add, one floor, one compare
        self.frac_bounds = torch.stack((self.frac_low - EXACT_MARGIN, self.frac_high + EXACT_MARGIN))  # (2, G, 2)
        self.shift_low = (-TILE - whole_low).to(torch.float64)
        self.shift_high = (screen + TILE - 1 - whole_high).to(torch.float64)

    def _pixels(self, config: torch.Tensor, whole: torch.Tensor, first: torch.Tensor,
                n_configs: int) -> torch.Tensor:
        """The points' padded pixels at ``theta = 0`` as the counts read them; returns ``(G,)`` int64 each group's
        number within its configuration.

        Args (P points in group order, G groups): ``config`` ``(P,)`` int64 each point's configuration;
        ``whole`` ``(P, 2)`` int64 its whole screen ``(row, col)``; ``first`` ``(G,)`` int64 each group's first
        point; ``n_configs`` ``N``.
        """
        height, width = self.camera.screen_shape
        device, n_groups = config.device, first.shape[0]
        self.padded_shape = (height + 2 * TILE, width + 2 * TILE)
        padded_cells = self.padded_shape[0] * self.padded_shape[1]
        self.n_cells = n_configs * padded_cells
        cell = config * padded_cells + (whole[:, 0] + TILE) * self.padded_shape[1] + (whole[:, 1] + TILE)
        # ids = cumsum(steps): the steps between consecutive points' pixels are fixed inside a group;
        # at a group's first point the step also carries the change of shift from the previous group.
        self.first = first
        self.steps = torch.diff(cell, prepend=cell.new_zeros(1))
        self.first_steps = self.steps[first].to(torch.float64)  # exact: ids are far below 2^53
        self.flat_stride = torch.tensor([float(self.padded_shape[1]), 1.0], dtype=torch.float64, device=device)
        config_of_group = config[first]
        first_group = torch.searchsorted(config_of_group, torch.arange(n_configs, device=device))
        # For the compiled count (sdm.experiments.baselines.cmaes_native.pixel_mismatch): group and configuration bounds,
        # each point's padded pixel within its configuration, the limits of the trusted shifts.
        self.group_start = torch.cat((first, first.new_full((1,), config.numel())))
        self.config_group = torch.cat((first_group, first_group.new_full((1,), n_groups)))
        self.cells = (cell - config * padded_cells).to(torch.int32)
        self.limits = torch.tensor([*self.max_gain, EXACT_RANGE], dtype=torch.float64, device=device)
        return torch.arange(n_groups, device=device) - first_group[config_of_group]

    def table(self, targets: torch.Tensor, recycled: tuple[torch.Tensor, torch.Tensor] | None = None,
              compact: bool = False, active: torch.Tensor | None = None):
        """The per-run table of :meth:`PixelMismatch.many`.

        Args:
            targets: ``(N, H, W)`` bool.
            recycled: ``(table, on_target)`` of a finished run of this layout (of the same ``compact``),
                to rewrite in place instead of allocating and filling ``N * Hp * Wp`` entries again.
            compact: the compiled count's table: int8 weights + 1 alone (it keeps its own stamps).
            active: ``targets.nonzero()`` when the caller has it (it costs a pass over the targets).

        Returns:
            ``(table, high, on_target)``: ``(N * Hp * Wp,)`` int16 (int32 beyond 127 groups per
            configuration; int8 if ``compact``) whose low half is the pixel's weight + 1 (2 on screen
            off target, 0 on target, 1 in the margin); the ``(N * Hp * Wp,)`` strided view of its high
            halves (None if ``compact``); ``(K,)`` int64 the entries of the target pixels.
        """
        n_configs, height, width = targets.shape
        if active is None:
            active = targets.nonzero()  # (K, 3) config, row, col: faster than converting all N H W cells
        padded_height, padded_width = self.padded_shape
        on_target = (active[:, 0] * padded_height + active[:, 1] + TILE) * padded_width + active[:, 2] + TILE
        if recycled is None:
            dtype = torch.int8 if compact else self.table_dtype
            entries = torch.ones((n_configs, *self.padded_shape), dtype=dtype, device=targets.device)
            entries[:, TILE:TILE + height, TILE:TILE + width] = 2
            table = entries.view(-1)
        else:
            table, previous = recycled
            table.index_fill_(0, previous, 2)  # back to "on screen, off target"
        table.index_fill_(0, on_target, 0)
        high = None if compact else table.view(self.half_dtype)[1 if sys.byteorder == "little" else 0::2]
        return table, high, on_target

    def reference_terms(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(origin, gain, base, owner)`` of :meth:`PixelMismatch.reference`, made on its first call and kept
        (they depend on the points only: the runs of :func:`fit_runs` share them): ``(P, 2)`` float64
        screen ``(row, col)`` at ``theta = 0`` and pixels per metre of ``(b, a)`` (:func:`_projection`),
        ``(P,)`` int64 each point's configuration times ``H W``, and ``(N H W,)`` int32 scratch (any
        content) where each rendered point writes its number."""
        if self._reference is None:
            height, width = self.camera.screen_shape
            origin, gain = _projection(self._points, self.camera)
            base = torch.repeat_interleave(torch.arange(self._counts.shape[0], device=origin.device),
                                           self._counts) * (height * width)
            owner = torch.empty(self._counts.shape[0] * height * width, dtype=torch.int32, device=origin.device)
            self._reference = (origin, gain, base, owner)
        return self._reference

    @property
    def stamp(self) -> torch.Tensor:
        """``(Hp * Wp + 1,)`` int32 (uint32 to the C code) scratch of the compiled count, zero at first."""
        if self._stamp is None:
            self._stamp = torch.zeros(self.padded_shape[0] * self.padded_shape[1] + 1, dtype=torch.int32,
                                      device=self.gain.device)
        return self._stamp

    def rendered_ids(self, theta) -> torch.Tensor | None:
        """``(P,)`` int64 padded pixel ids of the points at ``theta`` (scratch, overwritten by the next call);
        None when some group's shift cannot be trusted (the caller counts by reference)."""
        a, b = float(theta[0]), float(theta[1])
        if not (math.isfinite(a) and math.isfinite(b)) or abs(b) * self.max_gain[0] > EXACT_RANGE \
                or abs(a) * self.max_gain[1] > EXACT_RANGE:
            return None
        shift = self.gain * torch.tensor([b, a], dtype=self.gain.dtype, device=self.gain.device)  # (G, 2) pixels
        bounds = torch.floor(self.frac_bounds + shift)  # (2, G, 2): the lowest and highest point's whole shift
        if not torch.equal(bounds[0], bounds[1]):
            return None
        whole = torch.clamp(bounds[0], self.shift_low, self.shift_high)  # (G, 2) rows, cols (whole numbers)
        offset = whole @ self.flat_stride  # (G,) flat shift of each group; float64 but exact integers
        first_steps = torch.diff(offset, prepend=offset.new_zeros(1)).add_(self.first_steps).to(torch.int64)
        return torch.cumsum(self.steps.scatter_(0, self.first, first_steps), 0, out=self.ids)


class MismatchMemo:
    """The compiled count's memory of its last candidates on one table (``sdm_pixel_mismatch``, ``kernel/mismatch.c``).

    The count of a configuration depends on its groups' whole shifts alone; near CMA-ES's convergence most
    configurations of a candidate shift exactly as in one of the last candidates', and take that sum instead
    of a pass over their points: the same integers, less memory traffic. Valid for one table only (one
    :class:`PixelMismatch`: its targets never change).

    Attributes:
        slots: ``L``, the candidates remembered (the latest ones; a call of ``K > L`` candidates first grows it).
        offsets: ``(L * G,)`` int64 each slot's group shifts; sums: ``(L * N,)`` int64 its per-configuration
            sums; state: ``(L + 1,)`` int64 each slot's validity, then the next slot to fill.
    """

    #: Two CMA-ES generations of the 2-D problem (pycma's population: 6).
    SLOTS = 12

    def __init__(self, layout: ShiftLayout, slots: int = SLOTS) -> None:
        self._layout = layout
        self._allocate(slots)

    def _allocate(self, slots: int) -> None:
        device, n_groups = self._layout.gain.device, self._layout.gain.shape[0]
        self.slots = int(slots)
        self.offsets = torch.empty(self.slots * n_groups, dtype=torch.int64, device=device)
        self.sums = torch.empty(self.slots * (self._layout.config_group.shape[0] - 1), dtype=torch.int64,
                                device=device)
        self.state = torch.zeros(self.slots + 1, dtype=torch.int64, device=device)

    def holding(self, n_candidates: int) -> "MismatchMemo":
        """This memo, grown (and emptied) to at least ``n_candidates`` slots when it holds fewer."""
        if n_candidates > self.slots:
            self._allocate(n_candidates)
        return self


class PixelMismatch:
    """The exact zoom-0 pixel loss of a training set, as a function of ``theta``.

    Args:
        train_set: configurations (points ``Q``, targets ``L``).
        camera: camera and screen; default the set's own.
        layout: a :class:`ShiftLayout` of the same points and camera to share (:func:`fit_runs`);
            built here when None.
        recycle: a finished objective of the same layout whose table this one takes over (it is
            rewritten for these targets; ``recycle`` then counts by reference only).

    Attributes:
        evaluations: thetas counted so far.
        fallbacks: thetas counted by :meth:`reference` (a group's shift too close to a pixel border).
        native: whether the compiled count (:func:`sdm.experiments.baselines.cmaes_native.pixel_mismatch`) counts: CPU
            tensors and the kernel available (not ``SDM_NATIVE=0``), decided when the objective is built.
        table: ``(N * Hp * Wp,)`` int16 per padded pixel (:meth:`ShiftLayout.table`), 47 MB on the
            default data (512 configurations), or int8 (24 MB) for the compiled count; None when the
            layout is not usable (points more than ``EXACT_RANGE`` pixels off screen): then every
            theta is counted by :meth:`reference`.
    """

    def __init__(self, train_set: ConfigurationSet, camera: Camera | None = None,
                 layout: ShiftLayout | None = None, recycle: "PixelMismatch | None" = None) -> None:
        self.camera = camera or train_set.camera
        self.train_set = train_set
        self.layout = layout if layout is not None else ShiftLayout(train_set, self.camera)
        self.table = self.high = self.on_target = None
        self.native = self.layout.usable and serves(train_set.points, train_set.targets)
        self._active = train_set.targets.nonzero()  # (K, 3) config, row, col: for the table and the reference
        if self.layout.usable:
            recycled = None
            if (recycle is not None and recycle.layout is self.layout and recycle.table is not None
                    and recycle.native == self.native):
                recycled, recycle.table = (recycle.table, recycle.on_target), None
            self.table, self.high, self.on_target = self.layout.table(train_set.targets, recycled, self.native,
                                                                      self._active)
        self.n_target = int(self._active.shape[0])
        self._memo = MismatchMemo(self.layout) if self.native else None
        self.evaluations = 0
        self.fallbacks = 0

    def __call__(self, theta) -> int:
        """False positives + false negatives at zoom 0, summed over the configurations (pixels)."""
        return self.many([theta])[0]

    def many(self, thetas) -> list[int]:
        """:meth:`__call__` of each of ``K`` thetas (a CMA-ES generation): the compiled count takes them
        in one pass over the configurations, the torch count one after another; the same integers."""
        self.evaluations += len(thetas)
        if not self.native:
            return [self._count(theta) for theta in thetas]
        like = dict(dtype=torch.float64, device=self.table.device)
        candidates = torch.tensor([[float(theta[0]), float(theta[1])] for theta in thetas], **like).view(-1, 2)
        layout, memo = self.layout, self._memo.holding(len(thetas))
        counts = pixel_mismatch(
            thetas=candidates, gain=layout.gain, frac_bounds=layout.frac_bounds, shift_low=layout.shift_low,
            shift_high=layout.shift_high, group_start=layout.group_start, config_group=layout.config_group,
            cells=layout.cells, table=self.table, padded_shape=layout.padded_shape, limits=layout.limits,
            n_target=self.n_target, memo_offsets=memo.offsets, memo_sums=memo.sums, memo_state=memo.state,
            stamp=layout.stamp).tolist()
        for index, count in enumerate(counts):
            if count < 0:  # a group's shift too close to a pixel border for the shared shift
                self.fallbacks += 1
                counts[index] = self.reference(thetas[index])
        return counts

    def _count(self, theta) -> int:
        """The torch count of one theta (:meth:`many` without the compiled kernel)."""
        ids = self.layout.rendered_ids(theta) if self.table is not None else None
        if ids is None:
            self.fallbacks += 1
            return self.reference(theta)
        layout = self.layout
        self.high.scatter_(0, ids, layout.codes)  # the codes of stale writes need no clearing: all are overwritten
        # entry - own code in the high half: the weight + 1 (0, 1 or 2) for the point whose write survived,
        # at least 254 away for every other point. Clamped to [-1, 3], (c^2 - 1)(3 - c) is 3 times the
        # weight for a survivor (c = 0, 1, 2: -3, 0, 3) and 0 for the others (c = -1, 3): the sum of
        # weights in plain arithmetic passes (int16 ==/count_nonzero are several times slower here).
        clamped = self.table.gather(0, ids).sub_(layout.codes_high).clamp_(-1, 3)  # (P,)
        tripled = (clamped * clamped).sub_(1).mul_(clamped.neg_().add_(3))
        return self.n_target + int(tripled.sum()) // 3

    def reference(self, theta) -> int:
        """The same count, point by point: every point's own pixel, each pixel rendered counted once.

        The fallback of :meth:`many` where a group's shared shift cannot be trusted; no evaluation. Each
        point on screen writes its number into its pixel's entry of an ``N x H x W`` scratch; the point
        that reads its own number back stands for the pixel (counted once), nothing of that size is
        zeroed or counted: rendered pixels count -1 on target, +1 off it, beside ``|target|``.
        """
        height, width = self.camera.screen_shape
        origin, gain, base, owner = self.layout.reference_terms()
        shift = torch.tensor([float(theta[1]), float(theta[0])], dtype=origin.dtype, device=origin.device)
        pixels = torch.floor(torch.addcmul(origin, gain, shift)).to(torch.int64)  # (P, 2) row, col
        row, col = pixels.unbind(-1)
        keep = (row >= 0) & (row < height) & (col >= 0) & (col < width)
        ids = (base + row * width + col)[keep]
        number = torch.arange(ids.numel(), dtype=owner.dtype, device=owner.device)
        owner[ids] = number  # of several writes to one entry, one survives: which one does not matter
        rendered = ids[owner[ids] == number]  # (R,) each rendered pixel once
        overlap = int(self.train_set.targets.reshape(-1)[rendered].count_nonzero())
        return int(rendered.numel()) + int(self._active.shape[0]) - 2 * overlap
