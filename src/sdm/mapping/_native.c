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
