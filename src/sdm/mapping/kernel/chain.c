/* The layer's pass per level (sdm.mapping.native.chain) and the paper's flow at the loss level
 * (sdm.mapping.native.paper_flow): the zoom chain in one loop over the points per level, and eq. 19 in one more.
 */
#include "kernel.h"

/* The largest start pixel (either sign) sdm_chain takes: moved by less than 2^61 pixels over at most 60 levels,
 * it stays within int64. */
#define PIXEL_BOUND ((int64_t)1 << 61)

/* A point's rmin at the level before: it survives where its rank is the lowest that entered its cell (ranks
 * are distinct within a cell). The one that holds its cell's minimum resets the cell to no_rank as it reads
 * it: points after it read no_rank (not their rank: they lose, as they should), and every touched cell, the
 * sentinel too, has exactly one such point, so the table is all no_rank again once every point has read. */
static inline int rmin_survives(int64_t *table, int64_t own, int64_t rank, int64_t no_rank) {
    const int64_t least = table[own];
    const int won = least == rank;
    table[own] = won ? no_rank : least;
    return won;
}

/* One level of the zoom chain for points lo..hi-1, in one pass: each point first takes its rmin of the level
 * before from table `decided` (NULL at the first level, where every point is alive and starts at its pixel),
 * then, if alive, steps towards its projection (at most one block per axis) and, if on the grid, enters its
 * cell's rmin in table `entering` (the lowest rank is kept). The two tables alternate between levels, so a
 * level's entries are never mixed with the one before's. Points off the grid or dropped enter cell
 * `sentinel` (past every configuration's cells): no branch on them, and a point is alive exactly where its
 * cell is not the sentinel and it wins that cell (no separate alive row to store and load at every level).
 * `last` (the loss level) writes the
 * loss-level outputs; `first` and `last` are constants where this is inlined. */
static ALWAYS_INLINE void chain_level(
    int64_t lo, int64_t hi, int64_t level, int first, int last, const int64_t *projected, const int64_t *pixels,
    const int64_t *config, const int64_t *rank, int64_t height, int64_t width, int64_t *decided,
    int64_t *entering, int64_t sentinel, int64_t no_rank, uint8_t *entered, uint8_t *landed, int64_t *block_out,
    int64_t *landing_out, int64_t *current, int64_t *cell) {
    const int64_t size = (int64_t)1 << level, cells_per_config = height * width;
    const int64_t *from = first ? pixels : current;
    for (int64_t i = lo; i < hi; ++i) {
        /* alive after the level before: it entered a real cell (not the sentinel) and won it */
        const int was_alive = first ? 1 : (cell[i] != sentinel) & rmin_survives(decided, cell[i], rank[i], no_rank);
        const int64_t block_row = from[2 * i] >> level, block_col = from[2 * i + 1] >> level;
        /* landing block - input block, limited to the 3x3 kernel */
        const int64_t step_row = clamp_unit(wrapping_sub(projected[2 * i] >> level, block_row));
        const int64_t step_col = clamp_unit(wrapping_sub(projected[2 * i + 1] >> level, block_col));
        if (last) {
            entered[i] = (uint8_t)was_alive;
            block_out[2 * i] = block_row;
            block_out[2 * i + 1] = block_col;
            landing_out[2 * i] = block_row + step_row;
            landing_out[2 * i + 1] = block_col + step_col;
        }
        const int64_t row = from[2 * i] + step_row * size, col = from[2 * i + 1] + step_col * size;
        current[2 * i] = row;
        current[2 * i + 1] = col;
        const int candidate = was_alive & on_grid(row, col, height, width);
        if (last) landed[i] = (uint8_t)candidate;
        const int64_t own = candidate ? (config ? config[i] * cells_per_config : 0) + row * width + col : sentinel;
        cell[i] = own;
        const int64_t least = entering[own];
        entering[own] = rank[i] < least ? rank[i] : least;
    }
}

/* Levels steps..zoom of the zoom chain for points lo..hi-1, which no other point shares a configuration with.
 * config NULL: all of them are one configuration. cell_min holds two tables of sentinel + 1 cells, used
 * level by level in turn (chain_level). Inlined into sdm_chain. */
static ALWAYS_INLINE void chain_range(
    int64_t lo, int64_t hi, const int64_t *projected, const int64_t *pixels, const int64_t *config,
    const int64_t *rank, int64_t height, int64_t width, int64_t steps, int64_t zoom, int64_t *cell_min,
    int64_t sentinel, int64_t no_rank, int64_t *out_pixels, uint8_t *entered, uint8_t *landed, int64_t *block_out,
    int64_t *landing_out, int64_t *current, int64_t *cell, uint8_t *alive) {
    int64_t *table[2] = {cell_min, cell_min + sentinel + 1};
#define LEVEL(level, first, last, decided, entering)                                                              \
    chain_level(lo, hi, level, first, last, projected, pixels, config, rank, height, width, decided, entering,      \
                sentinel, no_rank, entered, landed, block_out, landing_out, current, cell)
    if (steps == zoom) {
        LEVEL(zoom, 1, 1, NULL, table[0]);
    } else {
        LEVEL(steps, 1, 0, NULL, table[0]);
        for (int64_t level = steps - 1; level > zoom; --level)
            LEVEL(level, 0, 0, table[(steps - level - 1) & 1], table[(steps - level) & 1]);
        LEVEL(zoom, 0, 1, table[(steps - zoom - 1) & 1], table[(steps - zoom) & 1]);
    }
#undef LEVEL
    int64_t *decided = table[(steps - zoom) & 1];
    for (int64_t i = lo; i < hi; ++i) {
        alive[i] = (uint8_t)((cell[i] != sentinel) & rmin_survives(decided, cell[i], rank[i], no_rank));
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
 * cell_min:  (n_scratch,) scratch, at least 2 * (n_cells + 1) entries (two tables, see chain_range), every
 *            entry NO_RANK on entry and on return
 * Outputs, all (P, ...): out_pixels (-1 where dropped), entered, landed, block and landing
 * at the loss level (written for every point, as the torch path computes them).
 * Returns 0; -1 (nothing read or written beyond the inputs) where a configuration is negative or beyond the
 * tables n_scratch holds, -2 where a start pixel lies beyond +-PIXEL_BOUND (its moves would leave int64).
 *
 * Configurations never interact, so where the points come configuration by configuration
 * (config non-decreasing, as every packed batch is) the chain runs chunk by chunk of whole
 * configurations; otherwise over all points at once. The result is the same either way.
 */
int64_t sdm_chain(int64_t n_points, const int64_t *projected, const int64_t *pixels, const int64_t *config,
                  const int64_t *rank, int64_t height, int64_t width, int64_t steps, int64_t zoom, int64_t *cell_min,
                  int64_t n_scratch, int64_t no_rank, int64_t *out_pixels, uint8_t *entered, uint8_t *landed,
                  int64_t *block_out, int64_t *landing_out, int64_t *current, int64_t *cell, uint8_t *alive) {
    int sorted = 1, inside = 1;
    /* the highest and lowest configuration: cell_min must have 2 * ((last + 1) * height * width + 1) entries */
    int64_t last = 0, least = 0;
    for (int64_t i = 0; i < n_points; ++i) {
        if (i && config[i] < config[i - 1]) sorted = 0;
        if (config[i] > last) last = config[i];
        if (config[i] < least) least = config[i];
        inside &= (pixels[2 * i] >= -PIXEL_BOUND) & (pixels[2 * i] <= PIXEL_BOUND) &
                  (pixels[2 * i + 1] >= -PIXEL_BOUND) & (pixels[2 * i + 1] <= PIXEL_BOUND);
    }
    if (least < 0 || height < 1 || width < 1 || last >= (n_scratch / 2 - 1) / (height * width)) return -1;
    if (!inside) return -2;
    int64_t lo = 0;
    while (lo < n_points) {
        int64_t hi = n_points;
        if (sorted) {
            hi = lo + CHUNK_POINTS < n_points ? lo + CHUNK_POINTS : n_points;
            while (hi < n_points && config[hi] == config[hi - 1]) ++hi; /* end on a configuration boundary */
        }
        chain_range(lo, hi, projected, pixels, config, rank, height, width, steps, zoom, cell_min,
                    (last + 1) * height * width, no_rank, out_pixels, entered, landed, block_out, landing_out, current,
                    cell, alive);
        lo = hi;
    }
    return 0;
}

/* The paper's dynamic gradient flow at the loss level.
 *
 * screen:  (P, 2) projection P(p), (row, col) screen pixels
 * target:  (n, grid_h, grid_w) zoomed-out target, 0/1
 * Outputs: matched (P,), flow (P, 2) (x, y) = (col, row) pulls, zero where not pulled (the
 * caller zeroes it), pulled (p,) indices of the pulled points in ascending order and
 * window_l1 (p, 2) per axis the summed |p - T_q| over the pulling blocks (screen pixels).
 * Returns p, the number of pulled points; -1 (no target read) where a landed point's configuration is not one
 * of the n_configs targets, its landing block is off the grid or not beside its block.
 */
int64_t sdm_paper_flow(int64_t n_points, const double *screen, const int64_t *config, const uint8_t *landed,
                       const int64_t *block, const int64_t *landing, const uint8_t *target, int64_t n_configs,
                       int64_t grid_h, int64_t grid_w, int64_t zoom, uint8_t *matched, double *flow,
                       int64_t *pulled, double *window_l1) {
    const int64_t cells_per_config = grid_h * grid_w;
    const double block_size = (double)((int64_t)1 << zoom);
    int64_t n_pulled = 0;
    for (int64_t i = 0; i < n_points; ++i) {
        if (!landed[i]) {
            matched[i] = 0;
            continue;
        }
        const int64_t block_row = block[2 * i], block_col = block[2 * i + 1];
        const int64_t near_row = wrapping_sub(landing[2 * i], block_row);
        const int64_t near_col = wrapping_sub(landing[2 * i + 1], block_col);
        if (config[i] < 0 || config[i] >= n_configs || !on_grid(landing[2 * i], landing[2 * i + 1], grid_h, grid_w) ||
            near_row < -1 || near_row > 1 || near_col < -1 || near_col > 1)
            return -1;
        const uint8_t *own = target + config[i] * cells_per_config;
        matched[i] = own[landing[2 * i] * grid_w + landing[2 * i + 1]];
        if (matched[i]) continue;
        const int64_t landing_index = (landing[2 * i] - block_row) * 3 + (landing[2 * i + 1] - block_col) + 4;
        double pull[2], l1[2];
        window_pull(screen[2 * i], screen[2 * i + 1], block_row, block_col, landing_index, own, grid_h, grid_w,
                    block_size, pull, l1);
        flow[2 * i] = pull[1]; /* (row, col) -> (x, y) */
        flow[2 * i + 1] = pull[0];
        pulled[n_pulled] = i;
        window_l1[2 * n_pulled] = l1[0];
        window_l1[2 * n_pulled + 1] = l1[1];
        ++n_pulled;
    }
    return n_pulled;
}
