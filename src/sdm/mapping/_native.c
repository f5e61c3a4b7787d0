/* The SDM layer's CPU hot path in one pass per level: see sdm/mapping/native.py.
 *
 * Two functions, each the exact counterpart of a torch formulation in this package:
 *   sdm_chain        <-> the level loop of sdm.mapping.fast.fast_mapping
 *   sdm_paper_flow   <-> sdm.mapping.flow.dynamic_flow (the paper's eq. 19)
 * They do the same integer arithmetic and, for the few floating-point values, the same
 * operations in the same order, so their results equal the torch path's bit for bit
 * (tests/test_native.py holds it). Built with -ffp-contract=off: no fused multiply-adds.
 *
 * All arrays are C-contiguous; int64 for integers, uint8 (0/1) for bool, double for floats.
 */
#include <stdint.h>

static inline int64_t clamp_unit(int64_t value) { return value < -1 ? -1 : (value > 1 ? 1 : value); }

static inline int on_grid(int64_t row, int64_t col, int64_t height, int64_t width) {
    return row >= 0 && row < height && col >= 0 && col < width;
}

/* Levels steps..zoom of the zoom chain for points lo..hi-1, which no other point shares a configuration with. */
static void chain_range(int64_t lo, int64_t hi, const int64_t *projected, const int64_t *pixels,
                        const int64_t *config, const int64_t *rank, int64_t height, int64_t width, int64_t steps,
                        int64_t zoom, int64_t *cell_min, int64_t no_rank, int64_t *out_pixels, uint8_t *entered,
                        uint8_t *landed, int64_t *block_out, int64_t *landing_out, int64_t *current, int64_t *cell,
                        uint8_t *alive) {
    const int64_t cells_per_config = height * width;
    for (int64_t i = lo; i < hi; ++i) {
        current[2 * i] = pixels[2 * i];
        current[2 * i + 1] = pixels[2 * i + 1];
        alive[i] = 1;
    }
    for (int64_t level = steps; level >= zoom; --level) {
        const int64_t size = (int64_t)1 << level;
        for (int64_t i = lo; i < hi; ++i) {
            const int64_t block_row = current[2 * i] >> level, block_col = current[2 * i + 1] >> level;
            /* landing block - input block, limited to the 3x3 kernel */
            const int64_t step_row = clamp_unit((projected[2 * i] >> level) - block_row);
            const int64_t step_col = clamp_unit((projected[2 * i + 1] >> level) - block_col);
            if (level == zoom) {
                entered[i] = alive[i];
                block_out[2 * i] = block_row;
                block_out[2 * i + 1] = block_col;
                landing_out[2 * i] = block_row + step_row;
                landing_out[2 * i + 1] = block_col + step_col;
            }
            const int64_t row = current[2 * i] + step_row * size, col = current[2 * i + 1] + step_col * size;
            current[2 * i] = row;
            current[2 * i + 1] = col;
            const int candidate = alive[i] && on_grid(row, col, height, width);
            if (level == zoom) landed[i] = (uint8_t)candidate;
            alive[i] = (uint8_t)candidate;
            cell[i] = candidate ? config[i] * cells_per_config + row * width + col : -1;
            if (candidate && rank[i] < cell_min[cell[i]]) cell_min[cell[i]] = rank[i];
        }
        /* rmin: a point survives where its rank is the lowest that landed in its cell */
        for (int64_t i = lo; i < hi; ++i)
            if (alive[i]) alive[i] = cell_min[cell[i]] == rank[i];
        for (int64_t i = lo; i < hi; ++i)
            if (cell[i] >= 0) cell_min[cell[i]] = no_rank;
    }
    for (int64_t i = lo; i < hi; ++i) {
        out_pixels[2 * i] = alive[i] ? current[2 * i] : -1;
        out_pixels[2 * i + 1] = alive[i] ? current[2 * i + 1] : -1;
    }
}

/* Points per chunk (at least): a chunk's rows and the cells they touch stay in cache through all levels. */
#define CHUNK_POINTS 2048

/* Levels steps..zoom of the zoom chain for n_points points.
 *
 * projected: (P, 2) floor of each point's projection, screen pixels (row, col)
 * pixels:    (P, 2) each point's pixel in I~ at the start
 * config:    (P,)   configuration index; rank: (P,) rmin priority (lower wins)
 * cell_min:  (n_cells + 1,) scratch, every entry NO_RANK on entry and on return
 * Outputs, all (P, ...): out_pixels (-1 where dropped), entered, landed, block and landing
 * at the loss level (written for every point, as the torch path computes them).
 *
 * Configurations never interact, so where the points come configuration by configuration
 * (config non-decreasing, as every packed batch is) the chain runs chunk by chunk of whole
 * configurations; otherwise over all points at once. The result is the same either way.
 */
void sdm_chain(int64_t n_points, const int64_t *projected, const int64_t *pixels, const int64_t *config,
               const int64_t *rank, int64_t height, int64_t width, int64_t steps, int64_t zoom, int64_t *cell_min,
               int64_t no_rank, int64_t *out_pixels, uint8_t *entered, uint8_t *landed, int64_t *block_out,
               int64_t *landing_out, int64_t *current, int64_t *cell, uint8_t *alive) {
    int sorted = 1;
    for (int64_t i = 1; i < n_points && sorted; ++i) sorted = config[i] >= config[i - 1];
    int64_t lo = 0;
    while (lo < n_points) {
        int64_t hi = n_points;
        if (sorted) {
            hi = lo + CHUNK_POINTS < n_points ? lo + CHUNK_POINTS : n_points;
            while (hi < n_points && config[hi] == config[hi - 1]) ++hi; /* end on a configuration boundary */
        }
        chain_range(lo, hi, projected, pixels, config, rank, height, width, steps, zoom, cell_min, no_rank,
                    out_pixels, entered, landed, block_out, landing_out, current, cell, alive);
        lo = hi;
    }
}

static inline double sign_of(double value) { return (double)((value > 0.0) - (value < 0.0)); }

/* The paper's dynamic gradient flow at the loss level.
 *
 * screen:  (P, 2) projection P(p), (row, col) screen pixels
 * target:  (n, grid_h, grid_w) zoomed-out target, 0/1
 * Outputs: matched (P,), flow (P, 2) (x, y) = (col, row) pulls, zero where not pulled (the
 * caller zeroes it), pulled (p,) indices of the pulled points in ascending order and
 * window_l1 (p, 2) per axis the summed |p - T_q| over the pulling blocks (screen pixels).
 * Returns p, the number of pulled points.
 */
int64_t sdm_paper_flow(int64_t n_points, const double *screen, const int64_t *config, const uint8_t *landed,
                       const int64_t *block, const int64_t *landing, const uint8_t *target, int64_t grid_h,
                       int64_t grid_w, int64_t zoom, uint8_t *matched, double *flow, int64_t *pulled,
                       double *window_l1) {
    const int64_t cells_per_config = grid_h * grid_w;
    const double block_size = (double)((int64_t)1 << zoom);
    int64_t n_pulled = 0;
    for (int64_t i = 0; i < n_points; ++i) {
        if (!landed[i]) {
            matched[i] = 0;
            continue;
        }
        const int64_t base = config[i] * cells_per_config;
        const int64_t block_row = block[2 * i], block_col = block[2 * i + 1];
        matched[i] = target[base + landing[2 * i] * grid_w + landing[2 * i + 1]];
        if (matched[i]) continue;
        const int64_t landing_index = (landing[2 * i] - block_row) * 3 + (landing[2 * i + 1] - block_col) + 4;
        double offset_row[3], offset_col[3], weight[3][3];
        int row_ok[3], col_ok[3];
        for (int k = 0; k < 3; ++k) {
            offset_row[k] = screen[2 * i] - (((double)block_row + (double)(k - 1)) + 0.5) * block_size;
            offset_col[k] = screen[2 * i + 1] - (((double)block_col + (double)(k - 1)) + 0.5) * block_size;
            row_ok[k] = block_row + k - 1 >= 0 && block_row + k - 1 < grid_h;
            col_ok[k] = block_col + k - 1 >= 0 && block_col + k - 1 < grid_w;
        }
        for (int k = 0; k < 3; ++k)
            for (int l = 0; l < 3; ++l) {
                const int in_grid = row_ok[k] && col_ok[l];
                const int64_t window_cell = base + (block_row + k - 1) * grid_w + (block_col + l - 1);
                weight[k][l] = (in_grid && target[window_cell] && 3 * k + l != landing_index) ? 1.0 : 0.0;
            }
        double per_row[3], per_col[3];
        for (int k = 0; k < 3; ++k) {
            per_row[k] = weight[k][0] + weight[k][1] + weight[k][2];
            per_col[k] = weight[0][k] + weight[1][k] + weight[2][k];
        }
        const double pull_row = sign_of(offset_row[0]) * per_row[0] + sign_of(offset_row[1]) * per_row[1] +
                                sign_of(offset_row[2]) * per_row[2];
        const double pull_col = sign_of(offset_col[0]) * per_col[0] + sign_of(offset_col[1]) * per_col[1] +
                                sign_of(offset_col[2]) * per_col[2];
        flow[2 * i] = pull_col; /* (row, col) -> (x, y) */
        flow[2 * i + 1] = pull_row;
        /* one term at a time in the window's row-major order, as sdm.mapping.flow._window_l1 adds them */
        double total_row = 0.0, total_col = 0.0;
        for (int k = 0; k < 3; ++k)
            for (int l = 0; l < 3; ++l) {
                total_row = total_row + __builtin_fabs(offset_row[k]) * weight[k][l];
                total_col = total_col + __builtin_fabs(offset_col[l]) * weight[k][l];
            }
        pulled[n_pulled] = i;
        window_l1[2 * n_pulled] = total_row;
        window_l1[2 * n_pulled + 1] = total_col;
        ++n_pulled;
    }
    return n_pulled;
}

/* ---- CMA-ES baseline: the exact zoom-0 pixel mismatch for many thetas (sdm/baselines/cmaes.py) ----
 *
 * sdm_pixel_mismatch <-> sdm.baselines.cmaes.ShiftLayout.rendered_ids + PixelMismatch's count: the same
 * float operations decide each group's whole shift and whether it can be trusted (one multiply, one
 * add and a floor per bound, as torch computes them elementwise), then an integer count. A candidate
 * whose shift cannot be trusted gets -1 and is counted by the torch reference (the caller's job).
 *
 * theta:        (K, 2) candidates (a, b), metres
 * gain:         (G, 2) pixels per metre (row per b, col per a) of each group
 * frac_bounds:  (2, G, 2) the group's lowest and highest sub-pixel offset, widened by the margin
 * shift_low, shift_high: (G, 2) clamp range of the group's whole shift (stays in the padded screen)
 * group_start:  (G + 1,) first point of each group (groups configuration by configuration)
 * config_group: (N + 1,) first group of each configuration
 * cells:        (P,) int32 each point's padded pixel at theta = 0, within its configuration
 * table:        (N * cells_per_config,) int8 per padded pixel its weight + 1 (0 on target, 2 on
 *               screen off target, 1 in the margin)
 * limits:       (3,) the largest |gain| (row, col) and the range up to which shifts are trusted
 * offsets:      (K * G,) int64 scratch; stamp: (cells_per_config + 1,) uint32 scratch, its last entry
 *               the last stamp used (all zero at first, then only ever written here)
 * counts:       (K,) out, false positives + false negatives, or -1
 */
void sdm_pixel_mismatch(int64_t n_candidates, const double *theta, int64_t n_groups, int64_t n_configs,
                        const double *gain, const double *frac_bounds, const double *shift_low,
                        const double *shift_high, const int64_t *group_start, const int64_t *config_group,
                        const int32_t *cells, const int8_t *table, int64_t cells_per_config, int64_t padded_width,
                        const double *limits, int64_t n_target, int64_t *offsets, uint32_t *stamp,
                        int64_t *counts) {
    const double *frac_high = frac_bounds + 2 * n_groups;
    const double max_gain_row = limits[0], max_gain_col = limits[1], exact_range = limits[2];
    for (int64_t k = 0; k < n_candidates; ++k) {
        const double a = theta[2 * k], b = theta[2 * k + 1];
        counts[k] = -1;
        /* as ShiftLayout.rendered_ids: non-finite or too far, then every group's bounds */
        if (!(a - a == 0.0 && b - b == 0.0) || __builtin_fabs(b) * max_gain_row > exact_range ||
            __builtin_fabs(a) * max_gain_col > exact_range)
            continue;
        int64_t *offset = offsets + k * n_groups;
        int trusted = 1;
        for (int64_t g = 0; g < n_groups && trusted; ++g) {
            const double shift_row = gain[2 * g] * b, shift_col = gain[2 * g + 1] * a;
            const double low_row = __builtin_floor(frac_bounds[2 * g] + shift_row);
            const double low_col = __builtin_floor(frac_bounds[2 * g + 1] + shift_col);
            trusted = low_row == __builtin_floor(frac_high[2 * g] + shift_row) &&
                      low_col == __builtin_floor(frac_high[2 * g + 1] + shift_col);
            /* torch.clamp(x, low, high) = min(max(x, low), high) */
            double row = low_row < shift_low[2 * g] ? shift_low[2 * g] : low_row;
            double col = low_col < shift_low[2 * g + 1] ? shift_low[2 * g + 1] : low_col;
            row = row > shift_high[2 * g] ? shift_high[2 * g] : row;
            col = col > shift_high[2 * g + 1] ? shift_high[2 * g + 1] : col;
            offset[g] = (int64_t)row * padded_width + (int64_t)col;
        }
        if (trusted) counts[k] = n_target; /* plus FP - TP so far: never below 0 while it adds up */
    }
    /* Stamps tell which padded pixels a candidate has rendered in the current configuration: one per
     * (configuration, candidate), never reused before the array is wiped, so nothing is cleared per pass. */
    uint32_t last = stamp[cells_per_config];
    if ((uint64_t)last + (uint64_t)(n_configs * n_candidates) >= (uint64_t)UINT32_MAX) {
        for (int64_t i = 0; i <= cells_per_config; ++i) stamp[i] = 0;
        last = 0;
    }
    /* Configuration by configuration, every candidate: its pixels stay in cache across the candidates. */
    for (int64_t c = 0; c < n_configs; ++c) {
        const int8_t *weights = table + c * cells_per_config;
        for (int64_t k = 0; k < n_candidates; ++k) {
            if (counts[k] < 0) continue;
            const uint32_t mark = ++last;
            const int64_t *offset = offsets + k * n_groups;
            int64_t sum = 0;
            for (int64_t g = config_group[c]; g < config_group[c + 1]; ++g) {
                const int64_t shift = offset[g];
                for (int64_t p = group_start[g]; p < group_start[g + 1]; ++p) {
                    const int64_t id = (int64_t)cells[p] + shift;
                    if (stamp[id] != mark) { /* a pixel covered twice counts once (rare: well predicted) */
                        stamp[id] = mark;
                        sum += (int64_t)weights[id] - 1;
                    }
                }
            }
            counts[k] += sum;
        }
    }
    stamp[cells_per_config] = last;
}
