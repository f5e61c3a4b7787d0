/* The SDM layer's CPU hot path in one pass per level, and whole training runs: see sdm/mapping/native.py.
 *
 * Three functions, each the exact counterpart of a torch formulation in this package (and two more below:
 * sdm_noise_fill, sdm.sky.add_target_noise's scatter into a reused buffer; the CMA-ES baseline's count):
 *   sdm_chain        <-> the level loop of sdm.mapping.fast.fast_mapping
 *   sdm_paper_flow   <-> sdm.mapping.flow.dynamic_flow (the paper's eq. 19)
 *   sdm_train        <-> sdm.train.train_runs on the torch path (projection, chain, flow, SGD), for the
 *                        paper's rule and "closed_centred_r1" (sdm.mapping.rules)
 * They do the same integer arithmetic and, for the floating-point values, the same operations in
 * the same order, so their results equal the torch path's bit for bit (tests/test_native.py holds
 * it); only sdm_train's loss is summed in another order (see there). Built with -ffp-contract=off:
 * no fused multiply-adds.
 *
 * Speed without changing a bit (sdm_train): built with -O3, so loops are vectorised, but a
 * float loop only elementwise: without -ffast-math (-fassociative-math) the compiler never reorders
 * float operations, and a vector lane of add, multiply, divide or floor rounds exactly as its scalar
 * form (IEEE: each correctly rounded). Sums over points whose order matters stay scalar loops: the
 * loss (compensated) and the flow (integers, exact in any order anyway). All the freedom is taken in
 * the integer work: the trainer's chain runs in int32 lanes, loops split so that the per-coordinate
 * arithmetic vectorises apart from the rmin tables' gathers and scatters. sdm_train is compiled twice
 * in one library, plain x86-64 and AVX2, and picks at run time by the CPU (__builtin_cpu_supports): the
 * cached library is the same on every x86-64, so the cache key needs no -march.
 *
 * All arrays are C-contiguous; int64 for integers, uint8 (0/1) for bool, double for floats.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

static inline int64_t clamp_unit(int64_t value) { return value < -1 ? -1 : (value > 1 ? 1 : value); }

/* The largest start pixel (either sign) sdm_chain takes: moved by less than 2^61 pixels over at most 60 levels,
 * it stays within int64. */
#define PIXEL_BOUND ((int64_t)1 << 61)

/* a - b wrapping around as torch's int64 subtraction does (defined in C where a signed subtraction is not): a
 * projection floored from NaN or beyond int64 is INT64_MIN, as torch's .long() gives it, and the step towards it
 * must be torch's. */
static inline int64_t wrapping_sub(int64_t a, int64_t b) { return (int64_t)((uint64_t)a - (uint64_t)b); }

static inline int on_grid(int64_t row, int64_t col, int64_t height, int64_t width) {
    return row >= 0 && row < height && col >= 0 && col < width;
}

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
static inline __attribute__((always_inline)) void chain_level(
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
 * level by level in turn (chain_level). Inlined into each caller (sdm_train's copy is specialised to
 * config NULL). */
static inline __attribute__((always_inline)) void chain_range(
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
        inside &= pixels[2 * i] >= -PIXEL_BOUND & pixels[2 * i] <= PIXEL_BOUND & pixels[2 * i + 1] >= -PIXEL_BOUND &
                  pixels[2 * i + 1] <= PIXEL_BOUND;
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
                    (last + 1) * height * width, no_rank, out_pixels, entered, landed, block_out, landing_out, current, cell, alive);
        lo = hi;
    }
    return 0;
}

static inline double sign_of(double value) { return (double)((value > 0.0) - (value < 0.0)); }

/* The 3x3 window of one pulled point: the one formulation of "which blocks pull, and how".
 *
 * The window is centred on block (centre_row, centre_col) of a grid_h x grid_w target (one
 * configuration's, 0/1); its block at window index `skip` (row-major, 0..8: the landing block)
 * does not pull. A block pulls when it is on the grid, active and not skipped. Writes
 * pull (row, col): the summed sign(p - T_q) of the point at screen (row, col) over the pulling
 * blocks T_q (centres in screen pixels, blocks of block_size pixels), and l1 (row, col): the
 * summed |p - T_q|, one term at a time in row-major order (as sdm.mapping.flow._window_l1).
 * The paper's flow centres it on the input block (skip: the landing block's index); the
 * closed_centred_r1 rule at zoom 0 on the landing block (skip 4).
 */
static inline void window_pull(double screen_row, double screen_col, int64_t centre_row, int64_t centre_col,
                               int64_t skip, const uint8_t *target, int64_t grid_h, int64_t grid_w,
                               double block_size, double pull[2], double l1[2]) {
    double offset_row[3], offset_col[3], weight[3][3];
    int row_ok[3], col_ok[3];
    for (int k = 0; k < 3; ++k) {
        offset_row[k] = screen_row - (((double)centre_row + (double)(k - 1)) + 0.5) * block_size;
        offset_col[k] = screen_col - (((double)centre_col + (double)(k - 1)) + 0.5) * block_size;
        row_ok[k] = centre_row + k - 1 >= 0 && centre_row + k - 1 < grid_h;
        col_ok[k] = centre_col + k - 1 >= 0 && centre_col + k - 1 < grid_w;
    }
    /* Without branches (the target's blocks are as good as random to a predictor): a block off the grid
     * reads block 0, always there, and is masked out. */
    for (int k = 0; k < 3; ++k)
        for (int l = 0; l < 3; ++l) {
            const int in_grid = row_ok[k] & col_ok[l];
            const int64_t index = in_grid ? (centre_row + k - 1) * grid_w + (centre_col + l - 1) : 0;
            weight[k][l] = (double)(in_grid & (target[index] != 0) & (3 * k + l != skip));
        }
    double per_row[3], per_col[3];
    for (int k = 0; k < 3; ++k) {
        per_row[k] = weight[k][0] + weight[k][1] + weight[k][2];
        per_col[k] = weight[0][k] + weight[1][k] + weight[2][k];
    }
    /* integers: exact in any order */
    pull[0] = sign_of(offset_row[0]) * per_row[0] + sign_of(offset_row[1]) * per_row[1] +
              sign_of(offset_row[2]) * per_row[2];
    pull[1] = sign_of(offset_col[0]) * per_col[0] + sign_of(offset_col[1]) * per_col[1] +
              sign_of(offset_col[2]) * per_col[2];
    double total_row = 0.0, total_col = 0.0;
    for (int k = 0; k < 3; ++k)
        for (int l = 0; l < 3; ++l) {
            total_row = total_row + __builtin_fabs(offset_row[k]) * weight[k][l];
            total_col = total_col + __builtin_fabs(offset_col[l]) * weight[k][l];
        }
    l1[0] = total_row;
    l1[1] = total_col;
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

/* Two doubles as one SSE2 register: elementwise IEEE operations, each lane rounding as its scalar twin. */
typedef double pair __attribute__((vector_size(16)));

/* The cache lines of a few byte ranges, fetched a few at a time (prefetch_some) between pieces of other work: one
 * burst of hundreds of prefetches waits on the core's few line-fill buffers (that wait was a sixth of the
 * trainer's time), while a few at a time complete behind the work. The configurations of an epoch come in
 * shuffled order, so the hardware prefetcher cannot see the next one's rows coming (their first touch was a
 * fifth of the chain's time). */
typedef struct {
    const char *start[3];
    int64_t lines[3], next;
    int range;
} prefetch_plan;

static inline void plan_range(prefetch_plan *plan, int range, const void *start, int64_t bytes) {
    const uintptr_t first = (uintptr_t)start & ~(uintptr_t)63;
    plan->start[range] = (const char *)first;
    plan->lines[range] = bytes > 0 ? (int64_t)(((uintptr_t)start + (uintptr_t)bytes - first + 63) / 64) : 0;
}

static inline void prefetch_some(prefetch_plan *plan, int64_t count) {
    while (count > 0 && plan->range < 3) {
        if (plan->next < plan->lines[plan->range]) {
            __builtin_prefetch(plan->start[plan->range] + 64 * plan->next);
            ++plan->next, --count;
        } else {
            ++plan->range, plan->next = 0;
        }
    }
}

/* Neumaier's compensated sum: the loss adds thousands of positive terms per step. */
typedef struct {
    double sum, compensation;
} exact_sum;

static inline void sum_add(exact_sum *acc, double value) {
    const double total = acc->sum + value;
    if (__builtin_fabs(acc->sum) >= __builtin_fabs(value))
        acc->compensation += (acc->sum - total) + value;
    else
        acc->compensation += (value - total) + acc->sum;
    acc->sum = total;
}

/* ---- sdm_train's helpers: the set's points in the layout the loops read, the projection, the chain ---- */

/* The trainer's chain runs on int32 (half the bytes of int64 through the cache, twice the lanes per
 * vector); sdm_train refuses screens where that could overflow (returns -2; the caller takes the torch path). */
#define TRAIN_MAX_SIDE ((int64_t)1 << 24)
#define TRAIN_MAX_CELLS ((int64_t)1 << 30)
#define NO_RANK32 INT32_MAX
/* A start pixel beyond +-2^26 is clamped there: such a point is off the grid after the first level whatever
 * its step (steps move at most 2^24 pixels), so it is dropped as the int64 value is, and nothing of a
 * dropped point is read. A projected pixel beyond +-2^29 is clamped there: with sides of at most 2^24
 * pixels every point's position stays within 2^26 + 2^25, so (projected >> level) - block keeps its sign
 * and a magnitude of at least 2 at every level (level <= 24): the one-block step (clamp_unit) is the
 * one the int64 value gives. */
#define PIXEL_LIMIT ((int64_t)1 << 26)
#define PROJECTED_LIMIT 536870912.0

static int compare_pairs(const void *left, const void *right) {
    const int64_t *l = left, *r = right;
    return (l[0] > r[0]) - (l[0] < r[0]);
}

/* Ranks matter only by their order within a configuration (rmin keeps the lowest), and the trainer's rmin
 * tables hold int32: where every rank is in [0, INT32_MAX) they are used as they are (NULL), else this
 * returns a copy in which each configuration's ranks are replaced by their position in its sorted order
 * (equal ranks stay equal), or sets *failed where no memory could be had. */
static int64_t *ranks_in_int32(int64_t n_configs, const int64_t *offsets, const int64_t *rank, int *failed) {
    const int64_t n_points = offsets[n_configs];
    int fits = 1;
    for (int64_t i = 0; i < n_points; ++i) fits &= rank[i] >= 0 && rank[i] < NO_RANK32;
    if (fits) return NULL;
    int64_t *dense = malloc(sizeof(int64_t) * (size_t)(n_points ? n_points : 1));
    int64_t *pairs = malloc(sizeof(int64_t) * 2 * (size_t)(n_points ? n_points : 1));
    if (!dense || !pairs) {
        free(dense), free(pairs);
        *failed = 1;
        return NULL;
    }
    for (int64_t c = 0; c < n_configs; ++c) {
        const int64_t lo = offsets[c], n = offsets[c + 1] - lo;
        for (int64_t i = 0; i < n; ++i) pairs[2 * i] = rank[lo + i], pairs[2 * i + 1] = i;
        qsort(pairs, (size_t)n, 2 * sizeof(int64_t), compare_pairs);
        int64_t position = 0;
        for (int64_t i = 0; i < n; ++i) {
            if (i && pairs[2 * i] != pairs[2 * i - 2]) ++position;
            dense[lo + pairs[2 * i + 1]] = position;
        }
    }
    free(pairs);
    return dense;
}

static inline int32_t start_pixel(int64_t pixel) {
    return (int32_t)(pixel < -PIXEL_LIMIT ? -PIXEL_LIMIT : (pixel > PIXEL_LIMIT ? PIXEL_LIMIT : pixel));
}

/* floor(x) as int32, clamped to +-PROJECTED_LIMIT: torch.floor(x).long() clamped. Where x is NaN or floor(x)
 * is beyond int64 that is INT64_MIN (x86's conversion, as torch's .long() gives it there): -PROJECTED_LIMIT.
 * Comparisons and selects only, no branch. */
static inline int32_t floor_clamped(double x) {
    const double f = __builtin_floor(x);
    const double clamped = f < PROJECTED_LIMIT ? f : PROJECTED_LIMIT;
    return (int32_t)((f > -PROJECTED_LIMIT && f < 9223372036854775808.0) ? clamped : -PROJECTED_LIMIT);
}

/* The projection of one configuration's n points, point i moved by (a_i, b_i, 0) = shift[stride * i ..], as
 * sdm.camera.Camera.project evaluates it, to screen (row, col) = ((fy * y / z + cy) * rows_per_pixel - H,
 * (fx * x / z + cx) * cols_per_pixel - 0) and its floor. stride 0: one shift (a, b) for every point (the
 * paper's case); 2: a shift per point (parameters attached to points). Elementwise IEEE operations in the
 * torch path's order: a vectorised lane rounds as the scalar operation does (no reassociation without
 * -ffast-math, no fused multiply-add with -ffp-contract=off). */
static inline void project(int64_t n, const double *restrict q, const double *restrict shift, int64_t stride,
                           double fx, double fy, double cx, double cy, double rows_per_pixel, double cols_per_pixel,
                           double screen_height, double *restrict screen, int32_t *restrict projected) {
    for (int64_t i = 0; i < n; ++i) {
        const double a = shift[stride * i], b = shift[stride * i + 1];
        const double x = q[3 * i] + a, y = q[3 * i + 1] + b, z = q[3 * i + 2] + 0.0;
        const double row = ((fy * y) / z + cy) * rows_per_pixel - screen_height;
        const double col = ((fx * x) / z + cx) * cols_per_pixel - 0.0;
        screen[2 * i] = row;
        screen[2 * i + 1] = col;
        projected[2 * i] = floor_clamped(row);
        projected[2 * i + 1] = floor_clamped(col);
    }
}

/* Levels steps..zoom of the zoom chain for one configuration's n points: chain_level's integer arithmetic
 * (the same shifts, clamp, steps and rmin), in int32 (exact: TRAIN_MAX_SIDE, PROJECTED_LIMIT) so that a
 * vector holds twice the lanes and the working rows half the cache. Each level in three loops, so that
 * the one without memory dependences vectorises: which points survived the level before (gathers from
 * its rmin table, read and reset as rmin_survives), the step of every coordinate (the same operations on
 * each of the 2n lanes: vectorised), and the entries into this level's table (scatters). At the loss level
 * nothing enters (the trainer needs no rmin after it: landing is decided by the level before); instead
 * the points that land on the grid in a block the target leaves empty (the ones the flow pulls) are
 * listed in `pulled`, in ascending order, by a branchless append. The first level also prefetches the
 * target block each point will most likely land in. Returns the number pulled. */
static inline int64_t train_chain(int64_t n, const int32_t *restrict projected, const int32_t *restrict pixels,
                               const int32_t *restrict rank, int32_t height, int32_t width, int32_t steps,
                               int32_t zoom, int32_t *table[2], int32_t sentinel, const uint8_t *target,
                               int32_t grid_h, int32_t grid_w, int32_t *restrict current, int32_t *restrict block,
                               int32_t *restrict landing, int32_t *restrict cell, uint8_t *restrict alive,
                               int32_t *restrict pulled) {
    int64_t n_pulled = 0;
    for (int32_t level = steps; level >= zoom; --level) {
        const int first = level == steps, last = level == zoom;
        int32_t *decided = table[(steps - level + 1) & 1], *entering = table[(steps - level) & 1];
        if (!first)
            for (int64_t i = 0; i < n; ++i) {
                const int32_t own = cell[i], least = decided[own], won = least == rank[i];
                decided[own] = won ? NO_RANK32 : least;
                alive[i] = (uint8_t)((own != sentinel) & won);
            }
        const int32_t size = (int32_t)1 << level;
        if (last)
            for (int64_t j = 0; j < 2 * n; ++j) {
                const int32_t from = first ? pixels[j] : current[j];
                const int32_t here = from >> level, ahead = (projected[j] >> level) - here;
                const int32_t step = ahead < -1 ? -1 : (ahead > 1 ? 1 : ahead);
                block[j] = here;
                landing[j] = here + step;
                current[j] = from + step * size;
            }
        else
            for (int64_t j = 0; j < 2 * n; ++j) {
                const int32_t from = first ? pixels[j] : current[j];
                const int32_t here = from >> level, ahead = (projected[j] >> level) - here;
                const int32_t step = ahead < -1 ? -1 : (ahead > 1 ? 1 : ahead);
                current[j] = from + step * size;
            }
        if (last)
            for (int64_t i = 0; i < n; ++i) {
                const int on = ((uint32_t)current[2 * i] < (uint32_t)height) &
                               ((uint32_t)current[2 * i + 1] < (uint32_t)width);
                const int landed = (first ? 1 : alive[i]) & on;
                /* landed in a block the target leaves empty: pulled (branchless; block 0 is always there) */
                const int32_t index = landed ? landing[2 * i] * grid_w + landing[2 * i + 1] : 0;
                pulled[n_pulled] = (int32_t)i;
                n_pulled += landed & (target[index] == 0);
            }
        else
            for (int64_t i = 0; i < n; ++i) {
                const int32_t row = current[2 * i], col = current[2 * i + 1];
                const int candidate = (first ? 1 : alive[i]) & ((uint32_t)row < (uint32_t)height) &
                                      ((uint32_t)col < (uint32_t)width);
                const int32_t own = candidate ? row * width + col : sentinel, own_rank = rank[i];
                cell[i] = own;
                const int32_t least = entering[own];
                entering[own] = own_rank < least ? own_rank : least;
                if (first) { /* the target block it will most likely land in, read by the flow after the chain */
                    const int32_t near_row = projected[2 * i] >> zoom, near_col = projected[2 * i + 1] >> zoom;
                    if ((uint32_t)near_row < (uint32_t)grid_h && (uint32_t)near_col < (uint32_t)grid_w)
                        __builtin_prefetch(target + near_row * grid_w + near_col);
                }
            }
    }
    return n_pulled;
}

#if defined(__GNUC__) && defined(__x86_64__)
#include <immintrin.h>
#define TRAIN_AVX2 1
/* project() two points per AVX2 register: lanes (row, col, row, col), the same IEEE operations in the same
 * order on each lane as the scalar loop (vaddpd, vmulpd, vdivpd, vsubpd round as their scalar forms;
 * vroundpd's floor is exact), the clamp by compare and blend as floor_clamped's selects. */
__attribute__((target("avx2"), noinline)) static void project_avx2(
    int64_t n, const double *restrict q, const double *restrict shifts, int64_t stride, double fx, double fy,
    double cx, double cy, double rows_per_pixel, double cols_per_pixel, double screen_height,
    double *restrict screen, int32_t *restrict projected) {
    const double a = shifts[0], b = shifts[1];
    const __m256d shared = _mm256_set_pd(a, b, a, b), focal = _mm256_set_pd(fx, fy, fx, fy);
    const __m256d centre = _mm256_set_pd(cx, cy, cx, cy);
    const __m256d per_pixel = _mm256_set_pd(cols_per_pixel, rows_per_pixel, cols_per_pixel, rows_per_pixel);
    const __m256d origin = _mm256_set_pd(0.0, screen_height, 0.0, screen_height);
    const __m256d limit = _mm256_set1_pd(PROJECTED_LIMIT), low = _mm256_set1_pd(-PROJECTED_LIMIT);
    const __m256d int64_end = _mm256_set1_pd(9223372036854775808.0);
    int64_t i = 0;
    for (; i + 2 <= n; i += 2) {
        const double *p = q + 3 * i;
        const double z0 = p[2] + 0.0, z1 = p[5] + 0.0;
        const double *own = shifts + stride * i; /* (a_i, b_i, a_i+1, b_i+1) with stride 2 */
        const __m256d shift = stride ? _mm256_set_pd(own[2], own[3], own[0], own[1]) : shared;
        const __m256d moved = _mm256_add_pd(_mm256_set_pd(p[3], p[4], p[0], p[1]), shift); /* (y, x, y, x) */
        const __m256d uv = _mm256_add_pd(_mm256_div_pd(_mm256_mul_pd(focal, moved), _mm256_set_pd(z1, z1, z0, z0)),
                                         centre);
        const __m256d on_screen = _mm256_sub_pd(_mm256_mul_pd(uv, per_pixel), origin);
        _mm256_storeu_pd(screen + 2 * i, on_screen);
        const __m256d f = _mm256_floor_pd(on_screen);
        const __m256d clamped = _mm256_blendv_pd(limit, f, _mm256_cmp_pd(f, limit, _CMP_LT_OQ));
        const __m256d ok = _mm256_and_pd(_mm256_cmp_pd(f, low, _CMP_GT_OQ), _mm256_cmp_pd(f, int64_end, _CMP_LT_OQ));
        _mm_storeu_si128((__m128i *)(projected + 2 * i), _mm256_cvttpd_epi32(_mm256_blendv_pd(low, clamped, ok)));
    }
    project(n - i, q + 3 * i, shifts + stride * i, stride, fx, fy, cx, cy, rows_per_pixel, cols_per_pixel,
            screen_height, screen + 2 * i, projected + 2 * i);
}
#endif
/* One level up a pyramid of 0/1 targets: n targets of h x w (h, w even) to h/2 x w/2, each block the OR of its
 * 2 x 2 (sdm.zoom.target_pyramid; exact in any order). The n targets' rows are one array of n * h rows, so
 * output row t is the OR of input rows 2t and 2t + 1. */
static void halve_targets(int64_t n, int64_t h, int64_t w, const uint8_t *restrict finer, uint8_t *restrict coarser) {
    for (int64_t t = 0; t < n * (h / 2); ++t) {
        const uint8_t *top = finer + 2 * t * w, *bottom = top + w;
        uint8_t *out = coarser + t * (w / 2);
        for (int64_t c = 0; c < w / 2; ++c)
            out[c] = (uint8_t)((top[2 * c] | top[2 * c + 1]) | (bottom[2 * c] | bottom[2 * c + 1]));
    }
}

/* Whether any of n_runs runs (targets: their rows of n_levels addresses) leaves a level above 0 to the kernel to zoom out (its pyramid then fills `pyramid`). */
static int zooms_any(int64_t n_runs, int64_t n_levels, const int64_t *targets, const int64_t *levels) {
    for (int64_t run = 0; run < n_runs; ++run)
        for (int64_t li = 0; li < n_levels; ++li)
            if (targets[run * n_levels + li] == 0 && levels[li] > 0) return 1;
    return 0;
}

/* The active pixels of a 0/1 byte grid of n cells: eight bytes to a word, summed in 16-bit lanes (each lane
 * holds at most 2 * 255 after 255 words), so the loop streams the grid instead of widening every byte to
 * 64 bits; the rest byte by byte. */
static int64_t count_active(int64_t n, const uint8_t *grid) {
    const uint64_t low_bytes = 0x00FF00FF00FF00FFull;
    int64_t total = 0, at = 0;
    while (at + 8 <= n) {
        uint64_t lanes = 0;
        for (int64_t words = 0; words < 255 && at + 8 <= n; ++words, at += 8) {
            uint64_t word;
            __builtin_memcpy(&word, grid + at, 8);
            lanes += (word & low_bytes) + ((word >> 8) & low_bytes);
        }
        total += (int64_t)((lanes * 0x0001000100010001ull) >> 48);
    }
    for (; at < n; ++at) total += grid[at] != 0;
    return total;
}

/* ---- group_crossing at zoom 0 (sdm.mapping.crossing.group_crossing_flow) ----
 *
 * One configuration's flow summed into (grad_a, grad_b) and its exact pixel mismatch, from its n points'
 * projections (screen, and their floors in `projected`, as project() leaves them). The points are grouped
 * rigidly (crossing.rigid_groups: one configuration, one depth): group g lists its points' indices
 * within the configuration, ascending, at members[group_start[g] .. group_start[g + 1]).
 *
 * group_move_changes, integer for integer: `cover` counts the points per on-screen pixel (all zero on entry,
 * left so); a group's pixels near the screen (up to CROSSING_MARGIN off it) are stamped into `stamp`, a grid
 * padded by CROSSING_MARGIN + 1, with a stamp no other group used (stamp[padded_cells] holds the last one),
 * so "a point of the same group covers that pixel" is one load. For each of the moves y+, y-, x+, x-: a pixel
 * the group leaves (covered by this point alone, not covered again by the moved group) adds 1 if the target
 * holds it, else removes 1; a pixel it arrives in (on the screen, not its own, covered by no point) removes 1
 * if the target holds it, else adds 1. The flow of the group's crossings: per axis
 * scale * (lower(-e) K(behind) - lower(+e) K(ahead)), K = floor(max(0, 1 - d / width) * steps) / steps of the
 * distance d in metres (sub-pixel offset of the group's first point over its pixels per metre), in the torch
 * rule's operations and order; every term an exact binary fraction, so the sums are exact in any order.
 * crossing: (width, scale, steps), the level's. Returns the configuration's mismatch (false positives + false
 * negatives), given n_target, its target's active pixels.
 */
#define CROSSING_MARGIN 2

static inline double crossing_kernel(double distance, double width, double steps) {
    double x = 1.0 - distance / width;
    x = x < 0.0 ? 0.0 : x;
    return __builtin_floor(x * steps) / steps;
}

/* crossing_pull's integer part: each group's lowered changes lower[4 * g + k] (the moves' mismatch changes
 * where they lower it, else 0) and the configuration's mismatch, from its points' pixels alone. */
static int64_t crossing_changes(int64_t n, const int32_t *restrict projected, int64_t g_lo, int64_t g_hi,
                                const int64_t *restrict group_start, const int32_t *restrict members,
                                const uint8_t *restrict target, int64_t height, int64_t width, int32_t *restrict cover,
                                uint32_t *restrict stamp, int64_t padded_cells, int64_t n_target,
                                int32_t *restrict lower) {
    const int64_t margin = CROSSING_MARGIN, padded_width = width + 2 * (margin + 1);
    int64_t distinct = 0, hit = 0;
    for (int64_t i = 0; i < n; ++i) {
        const int64_t row = projected[2 * i], col = projected[2 * i + 1];
        if (row >= 0 && row < height && col >= 0 && col < width) {
            const int64_t at = row * width + col;
            if (cover[at]++ == 0) {
                ++distinct;
                hit += target[at] != 0;
            }
        }
    }
    static const int moves[4][2] = {{1, 0}, {-1, 0}, {0, 1}, {0, -1}};
    for (int64_t g = g_lo; g < g_hi; ++g) {
        if (stamp[padded_cells] >= UINT32_MAX - 1) { /* wipe before a stamp repeats */
            for (int64_t i = 0; i <= padded_cells; ++i) stamp[i] = 0;
        }
        const uint32_t mark = ++stamp[padded_cells];
        for (int64_t m = group_start[g]; m < group_start[g + 1]; ++m) {
            const int64_t i = members[m], row = projected[2 * i], col = projected[2 * i + 1];
            if (row >= -margin && row < height + margin && col >= -margin && col < width + margin)
                stamp[(row + margin + 1) * padded_width + (col + margin + 1)] = mark;
        }
        int64_t change[4] = {0, 0, 0, 0};
        for (int64_t m = group_start[g]; m < group_start[g + 1]; ++m) {
            const int64_t i = members[m], row = projected[2 * i], col = projected[2 * i + 1];
            if (!(row >= -margin && row < height + margin && col >= -margin && col < width + margin)) continue;
            const int on_screen = row >= 0 && row < height && col >= 0 && col < width;
            const int alone = on_screen && cover[row * width + col] == 1;
            const int64_t leave = on_screen && target[row * width + col] ? 1 : -1;
            const int64_t here = (row + margin + 1) * padded_width + (col + margin + 1);
            for (int k = 0; k < 4; ++k) {
                const int64_t step = moves[k][0] * padded_width + moves[k][1];
                if (alone && stamp[here - step] != mark) change[k] += leave;
                const int64_t to_row = row + moves[k][0], to_col = col + moves[k][1];
                if (to_row >= 0 && to_row < height && to_col >= 0 && to_col < width && stamp[here + step] != mark &&
                    cover[to_row * width + to_col] == 0)
                    change[k] += target[to_row * width + to_col] ? -1 : 1;
            }
        }
        for (int k = 0; k < 4; ++k) lower[4 * g + k] = change[k] < 0 ? (int32_t)-change[k] : 0;
    }
    for (int64_t i = 0; i < n; ++i) { /* leave cover all zero */
        const int64_t row = projected[2 * i], col = projected[2 * i + 1];
        if (row >= 0 && row < height && col >= 0 && col < width) cover[row * width + col] = 0;
    }
    return n_target + distinct - 2 * hit;
}

/* One configuration's crossing flow into grad and its mismatch (returned): group g's pull goes to the rows
 * of its first point (rows: the configuration's points' n_cols rows each; NULL: every point moves by row 0,
 * the paper's case), grad holding (grad_a, grad_b) per row. Its integer part
 * depends on the points' pixels alone, so where they are the ones of the configuration's last call in this
 * run (known: its mismatch >= 0, its pixels in known_pixels, 2n int32, its groups' lowered changes in
 * `lower`, 4 int32 per group), that part is taken as it was: the same integers; a refinement pass moves theta
 * by a fraction of a pixel, and in measured runs 89-96% of the configurations of a pass kept the pixels of
 * the pass before. The kernels are each group's own, from the sub-pixel offsets, always. */
static int64_t crossing_pull(int64_t n, const double *restrict screen, const int32_t *restrict projected,
                             const double *restrict q, int64_t g_lo, int64_t g_hi, const int64_t *restrict group_start,
                             const int32_t *restrict members, const uint8_t *restrict target, int64_t height,
                             int64_t width, double k_row, double k_col, const double *crossing, int32_t *restrict cover,
                             uint32_t *restrict stamp, int64_t padded_cells, int64_t n_target,
                             int32_t *restrict known_pixels, int32_t *restrict lower, int64_t *known_mismatch,
                             const int64_t *rows, int64_t n_cols, double *grad) {
    int same = *known_mismatch >= 0;
    for (int64_t j = 0; j < 2 * n && same; ++j) same = known_pixels[j] == projected[j];
    if (!same) {
        *known_mismatch = crossing_changes(n, projected, g_lo, g_hi, group_start, members, target, height, width,
                                           cover, stamp, padded_cells, n_target, lower);
        for (int64_t j = 0; j < 2 * n; ++j) known_pixels[j] = projected[j];
    }
    for (int64_t g = g_lo; g < g_hi; ++g) {
        double lowered[4];
        for (int k = 0; k < 4; ++k) lowered[k] = (double)lower[4 * g + k];
        const int64_t first = members[group_start[g]];
        const double z = q[3 * first + 2] + 0.0;
        const double gain_row = k_row / z, gain_col = k_col / z;
        const double sub_row = screen[2 * first] - __builtin_floor(screen[2 * first]);
        const double sub_col = screen[2 * first + 1] - __builtin_floor(screen[2 * first + 1]);
        const double ahead_row = crossing_kernel((1.0 - sub_row) / gain_row, crossing[0], crossing[2]);
        const double behind_row = crossing_kernel(sub_row / gain_row, crossing[0], crossing[2]);
        const double ahead_col = crossing_kernel((1.0 - sub_col) / gain_col, crossing[0], crossing[2]);
        const double behind_col = crossing_kernel(sub_col / gain_col, crossing[0], crossing[2]);
        const double pull_y = lowered[1] * behind_row - lowered[0] * ahead_row;
        const double pull_x = lowered[3] * behind_col - lowered[2] * ahead_col;
        /* every term an exact binary fraction: the sums are the same in any order and grouping */
        for (int64_t col = 0; col < (rows ? n_cols : 1); ++col) {
            const int64_t row = rows ? rows[first * n_cols + col] : 0;
            grad[2 * row] += crossing[1] * pull_x;
            grad[2 * row + 1] += crossing[1] * pull_y;
        }
    }
    return *known_mismatch;
}

/* closed_centred_r1's target: the 3x3 closing of one configuration's h x w 0/1 target (sdm.mapping.rules.closing(3),
 * _spread's OR then AND of the neighbours along rows, then columns; neighbours beyond the grid left out), from
 * src into dst through tmp (h * w bytes each). */
static void close3(int64_t h, int64_t w, const uint8_t *restrict src, uint8_t *restrict dst, uint8_t *restrict tmp) {
    for (int pass = 0; pass < 2; ++pass) { /* 0: dilation (OR), 1: erosion (AND) */
        const uint8_t *in = pass ? dst : src;
        for (int64_t r = 0; r < h; ++r) { /* along rows: in -> tmp */
            const uint8_t *row = in + r * w;
            uint8_t *out = tmp + r * w;
            if (w == 1) {
                out[0] = row[0];
                continue;
            }
            if (pass) {
                out[0] = row[0] & row[1];
                for (int64_t c = 1; c < w - 1; ++c) out[c] = row[c] & row[c - 1] & row[c + 1];
                out[w - 1] = row[w - 1] & row[w - 2];
            } else {
                out[0] = row[0] | row[1];
                for (int64_t c = 1; c < w - 1; ++c) out[c] = row[c] | row[c - 1] | row[c + 1];
                out[w - 1] = row[w - 1] | row[w - 2];
            }
        }
        for (int64_t r = 0; r < h; ++r) { /* along columns: tmp -> dst */
            const uint8_t *row = tmp + r * w, *up = r > 0 ? row - w : row, *down = r < h - 1 ? row + w : row;
            uint8_t *out = dst + r * w;
            if (pass)
                for (int64_t c = 0; c < w; ++c) out[c] = row[c] & up[c] & down[c];
            else
                for (int64_t c = 0; c < w; ++c) out[c] = row[c] | up[c] | down[c];
        }
    }
}

/* R whole training runs (sdm.train.train_runs): every level, epoch, mini-batch, chain, flow, loss and
 * SGD step, run after run (runs never interact, so each keeps its own targets hot in the cache).
 *
 * Data, shared by the runs (the packed ConfigurationSet, C-contiguous):
 *   offsets (N + 1,) row offsets; points (P, 3) q in metres; pixels (P, 2); rank (P,) rmin priority
 * camera:  fx, fy, cx, cy, rows_per_image_pixel, cols_per_image_pixel, fy * rows_per_image_pixel,
 *          fx * cols_per_image_pixel (the last two: metres per screen pixel are depth / them)
 * Levels:  levels (n_levels,) the loss level of each entry, one after another (each in 0..steps; the chain
 *          always starts at steps); rates (n_levels,) the learning rate of each; modes (n_levels,) the
 *          flow of each: 0 the paper's, 1 the closed_centred_r1 window (centred on the landing block, on the
 *          level's target closed by close3: the kernel closes each configuration's the first time a run
 *          needs it, into `pyramid`), 2 group_crossing (crossing_pull; level 0 only: it reads
 *          the chain's projections, not its survivors, so that level runs no chain)
 * groups:  for mode 2: config_group (N + 1,) each configuration's first group; group_start (G + 1,) and
 *          members (P,) int32 the groups' points (indices within their configuration, see crossing_pull);
 *          crossing (n_levels, 3) per level its kernel's half-width (metres), scale and steps (a refinement
 *          narrows the width pass by pass). Unread (may be 0) without mode 2.
 * orders:  (n_levels * n_epoch, R, N) each epoch's shuffling of each run
 * targets: (R, n_levels) addresses of run r's (N, H >> level, W >> level) 0/1 target at each level, 0
 *          where the kernel zooms it out itself from bases[r] (levels 1..steps of the run's pyramid, made
 *          once per run into `pyramid`); bases: (R,) address of run r's (N, H, W) 0/1 target
 * pyramid: scratch of N * sum over k = 1..steps of (H >> k) * (W >> k) bytes where any target above level 0
 *          is 0, then N * H * W more where any level is mode 1 (the closed targets), reused
 *          by the runs and (kept by the caller) the calls: in torch (zoom.target_pyramid) a noise run's
 *          pyramid cost a tenth of its training, most of it in the first touch of fresh pages
 * Parameters attached to points: theta is K rows (a, b); point i is moved by the sum of its n_cols rows
 *          param_index[i * n_cols ..] (in column order, as torch sums them). param_index NULL: K = 1 and every
 *          point moves by row 0 (the paper's shared shift). A row's flow is the sum of its points' flows.
 *          row_rate (K,): each row's factor on the level's rate (NULL: 1 for every row).
 * theta0:  (R, K, 2) starts (a, b), metres
 * Outputs: thetas (total / record_every + 1, R, K, 2) theta before the first step and after every
 *          record_every-th step; losses (total, R); failed (R,) the step (0-based) at which run r's theta
 *          became non-finite (the run stops there; later entries unwritten), -1 where it did not.
 *
 * A step of run r: point = q + (a, b, 0), (a, b) its rows' sum; the projection as sdm.camera.Camera.project evaluates it
 * (same operations, same order: project); the chain per configuration (train_chain: chain_level's
 * integer arithmetic in int32); the flow by
 * window_pull; grad = the summed flow per row (integers: exact in any order); theta = theta - rate * grad
 * (two roundings, as torch's theta -= rate * theta.grad) on the rows the batch's points move (the others'
 * grad is 0: theta - rate * 0 is theta, as torch's step leaves them). A batch without points pulls nothing. At a
 * mode-2 level the flow and loss are crossing_pull's (the loss: the mismatched pixels, summed exactly).
 * The loss is the sum over the pulled points of l1_row * (z / k_row) + l1_col * (z / k_col), the
 * products as sdm.mapping.flow.pull_loss forms them, the sum compensated in point order (torch's
 * .sum() adds in its own order, which is not reproduced: the two agree to the last bits,
 * tests/test_native.py holds them to 1e-12 relative). Theta never depends on the loss.
 * Returns 0, -1 where no memory could be had, -2 for a screen beyond the int32 chain (TRAIN_MAX_SIDE), or -3
 * for a level outside 0..steps or a mode-2 level above 0.
 */
#define TRAIN_PARAMETERS                                                                                         \
    int64_t n_runs, int64_t n_configs, const int64_t *offsets, const double *points, const int64_t *pixels,     \
        const int64_t *rank, int64_t height, int64_t width, const double *camera, int64_t steps, int64_t n_levels, \
        int64_t n_epoch, int64_t batch_size, const int64_t *levels, const double *rates, const uint8_t *modes,      \
        const int64_t *config_group, const int64_t *group_start, const int32_t *members, const double *crossing,   \
        const int64_t *orders, const int64_t *targets, const int64_t *bases, uint8_t *pyramid, int64_t no_rank,     \
        int64_t n_rows, int64_t n_cols, const int64_t *param_index, const double *row_rate, int64_t record_every,  \
        const double *theta0,                                                                                      \
        double *thetas, double *losses, int64_t *failed
#define TRAIN_ARGUMENTS                                                                                          \
    n_runs, n_configs, offsets, points, pixels, rank, height, width, camera, steps, n_levels, n_epoch, batch_size, \
        levels, rates, modes, config_group, group_start, members, crossing, orders, targets, bases, pyramid,       \
        no_rank, n_rows, n_cols, param_index, row_rate, record_every, theta0, thetas, losses, failed

/* Points projected per piece between prefetches (even: AVX2's pairs cover every piece but the last). */
#define PROJECT_PIECE 32

/* sdm_train's body, compiled once per instruction set it dispatches to (`wide`: AVX2's projection). */
static inline __attribute__((always_inline)) int64_t train_body(TRAIN_PARAMETERS, int wide) {
    (void)no_rank; /* the tables hold NO_RANK32 (ranks_in_int32) */
    const double fx = camera[0], fy = camera[1], cx = camera[2], cy = camera[3];
    const double rows_per_pixel = camera[4], cols_per_pixel = camera[5], k_row = camera[6], k_col = camera[7];
    const double screen_height = (double)height;
    const int64_t batches = n_configs / batch_size;
    if (height > TRAIN_MAX_SIDE || width > TRAIN_MAX_SIDE || height * width >= TRAIN_MAX_CELLS || steps > 62) return -2;
    int crosses = 0;
    for (int64_t li = 0; li < n_levels; ++li) {
        if (levels[li] < 0 || levels[li] > steps || (modes[li] == 2 && levels[li] != 0)) return -3;
        crosses |= modes[li] == 2;
    }
    int64_t largest = 1;
    for (int64_t c = 0; c < n_configs; ++c)
        if (offsets[c + 1] - offsets[c] > largest) largest = offsets[c + 1] - offsets[c];
    largest = (largest + 15) & ~(int64_t)15;
    const int32_t cells = (int32_t)(height * width), sentinel = cells;
    int no_memory = 0;
    int64_t *dense = ranks_in_int32(n_configs, offsets, rank, &no_memory);
    if (dense) rank = dense;
    /* the set's pixels (clamped: start_pixel) and ranks in int32, once for every run: the chain reads a
     * third fewer bytes per point than from the int64 rows */
    const int64_t n_points = offsets[n_configs];
    int32_t *pixels32 = malloc(sizeof(int32_t) * (size_t)(2 * n_points + 1));
    int32_t *rank32 = malloc(sizeof(int32_t) * (size_t)(n_points + 1));
    if (pixels32 && rank32) {
        for (int64_t j = 0; j < 2 * n_points; ++j) pixels32[j] = start_pixel(pixels[j]);
        for (int64_t i = 0; i < n_points; ++i) rank32[i] = (int32_t)rank[i];
    }
    /* one configuration's working rows and rmin cells */
    double *screen = malloc(sizeof(double) * (size_t)largest * 2);
    int32_t *rows = malloc(sizeof(int32_t) * (size_t)largest * 9);
    uint8_t *alive = malloc((size_t)largest);
    int32_t *cell_min = malloc(sizeof(int32_t) * (size_t)(2 * (cells + 1)));
    int32_t *pulled = malloc(sizeof(int32_t) * (size_t)largest);
    /* group_crossing's pixel counts and stamps, and each configuration's active target pixels (-1: not yet
     * counted; per run: its level-0 target) */
    const int64_t padded_cells = (height + 2 * (CROSSING_MARGIN + 1)) * (width + 2 * (CROSSING_MARGIN + 1));
    int32_t *cover = crosses ? calloc((size_t)cells, sizeof(int32_t)) : NULL;
    uint32_t *stamp = crosses ? calloc((size_t)(padded_cells + 1), sizeof(uint32_t)) : NULL;
    int64_t *n_target = crosses ? malloc(sizeof(int64_t) * (size_t)n_configs) : NULL;
    /* group_crossing's last pixels, lowered changes and mismatch of each configuration in this run (crossing_pull) */
    const int64_t n_groups = crosses ? config_group[n_configs] : 0;
    int32_t *known_pixels = crosses ? malloc(sizeof(int32_t) * (size_t)(2 * offsets[n_configs] + 1)) : NULL;
    int32_t *known_lower = crosses ? malloc(sizeof(int32_t) * (size_t)(4 * n_groups + 1)) : NULL;
    int64_t *known_mismatch = crosses ? malloc(sizeof(int64_t) * (size_t)n_configs) : NULL;
    /* the rows: each run's theta, a batch's summed flow per row, the rows it moved, each point's shift */
    const int64_t row_cols = param_index ? n_cols : 1;
    double *theta = malloc(sizeof(double) * (size_t)(2 * n_rows));
    double *grad = calloc((size_t)(2 * n_rows), sizeof(double));
    int64_t *moved_rows = malloc(sizeof(int64_t) * (size_t)(n_rows + 1));
    uint8_t *row_moved = calloc((size_t)n_rows + 1, 1);
    double *shift = param_index ? malloc(sizeof(double) * (size_t)largest * 2) : NULL;
    /* each configuration's distinct rows, row_list[config_rows[c] .. config_rows[c + 1]], listed once per call
     * (one pass over the points, a stamp per row): a step marks its configurations' rows, not every point's */
    int64_t *config_rows = param_index ? malloc(sizeof(int64_t) * (size_t)(n_configs + 1)) : NULL;
    int64_t *row_list = param_index ? malloc(sizeof(int64_t) * (size_t)(offsets[n_configs] * n_cols + 1)) : NULL;
    int64_t *row_stamp = param_index ? malloc(sizeof(int64_t) * (size_t)(n_rows + 1)) : NULL;
    if (config_rows && row_list && row_stamp) {
        for (int64_t k = 0; k < n_rows; ++k) row_stamp[k] = -1;
        config_rows[0] = 0;
        for (int64_t c = 0; c < n_configs; ++c) {
            int64_t listed = config_rows[c];
            for (int64_t j = offsets[c] * n_cols; j < offsets[c + 1] * n_cols; ++j)
                if (row_stamp[param_index[j]] != c) {
                    row_stamp[param_index[j]] = c;
                    row_list[listed++] = param_index[j];
                }
            config_rows[c + 1] = listed;
        }
    }
    int closes = 0;
    for (int64_t li = 0; li < n_levels; ++li) closes |= modes[li] == 1;
    uint8_t *closed_done = closes ? malloc((size_t)n_configs) : NULL, *close_tmp = closes ? malloc((size_t)cells) : NULL;
    /* where the zoomed-out levels 1..steps of a run's pyramid lie in `pyramid` */
    int64_t level_start[64] = {0};
    for (int64_t k = 2; k <= steps + 1; ++k)
        level_start[k] = level_start[k - 1] + n_configs * (height >> (k - 1)) * (width >> (k - 1));
    uint8_t *closed = pyramid + (zooms_any(n_runs, n_levels, targets, levels) ? level_start[steps + 1] : 0);
    int64_t code = 0;
    if (no_memory || !screen || !rows || !cell_min || !pulled || !alive || !pixels32 || !rank32 || !theta || !grad ||
        !moved_rows || !row_moved || (param_index && (!shift || !config_rows || !row_list || !row_stamp)) ||
        (crosses && (!cover || !stamp || !n_target || !known_pixels || !known_lower || !known_mismatch)) ||
        (closes && (!closed_done || !close_tmp))) {
        code = -1;
        goto done;
    }
    int32_t *projected = rows, *current = rows + 2 * largest, *block = rows + 4 * largest;
    int32_t *landing = rows + 6 * largest, *cell = rows + 8 * largest;
    for (int64_t i = 0; i < 2 * (cells + 1); ++i) cell_min[i] = NO_RANK32;
    int32_t *table[2] = {cell_min, cell_min + cells + 1};

    const int64_t run_size = 2 * n_rows; /* doubles of one run's theta */
    for (int64_t run = 0; run < n_runs; ++run) {
        for (int64_t k = 0; k < run_size; ++k) thetas[run * run_size + k] = theta[k] = theta0[run * run_size + k];
        failed[run] = -1;
        int64_t step = 0;
        const uint8_t *base = (const uint8_t *)(intptr_t)bases[run];
        const int zoom_run = zooms_any(1, n_levels, targets + run * n_levels, levels);
        const uint8_t *counted = NULL; /* the level-0 target whose active pixels n_target holds */
        const uint8_t *closing = NULL; /* the target whose configurations `closed` holds closed (closed_done) */
        for (int64_t k = 1; zoom_run && k <= steps; ++k)
            halve_targets(n_configs, height >> (k - 1), width >> (k - 1), k == 1 ? base : pyramid + level_start[k - 1],
                          pyramid + level_start[k]);
        for (int64_t li = 0; li < n_levels && failed[run] < 0; ++li) {
            const int64_t level = levels[li], grid_h = height >> level, grid_w = width >> level;
            const int64_t given = targets[run * n_levels + li];
            const uint8_t *target =
                given ? (const uint8_t *)(intptr_t)given : (level ? pyramid + level_start[level] : base);
            const double rate = rates[li], block_size = (double)((int64_t)1 << level);
            const int mode = modes[li];
            if (mode == 2 && counted != target) {
                for (int64_t c = 0; c < n_configs; ++c) n_target[c] = known_mismatch[c] = -1;
                counted = target;
            }
            if (mode == 1 && closing != target) {
                for (int64_t c = 0; c < n_configs; ++c) closed_done[c] = 0;
                closing = target;
            }
            for (int64_t epoch = 0; epoch < n_epoch && failed[run] < 0; ++epoch) {
                const int64_t *order = orders + ((li * n_epoch + epoch) * n_runs + run) * n_configs;
                for (int64_t batch = 0; batch < batches; ++batch) {
                    exact_sum loss = {0.0, 0.0};
                    int64_t n_moved = 0;
                    if (!param_index) { /* the shared shift: row 0 moves every point */
                        moved_rows[n_moved++] = 0;
                        row_moved[0] = 1;
                    }
                    for (int64_t j = 0; j < batch_size; ++j) {
                        const int64_t c = order[batch * batch_size + j];
                        const int64_t lo = offsets[c], n = offsets[c + 1] - lo;
                        const uint8_t *own = target + c * grid_h * grid_w;
                        const int64_t *own_rows = param_index ? param_index + lo * n_cols : NULL;
                        if (param_index) { /* each point's shift: its rows summed in column order */
                            for (int64_t k = config_rows[c]; k < config_rows[c + 1]; ++k)
                                if (!row_moved[row_list[k]]) {
                                    row_moved[row_list[k]] = 1;
                                    moved_rows[n_moved++] = row_list[k];
                                }
                            if (n_cols == 1)
                                for (int64_t i = 0; i < n; ++i) {
                                    shift[2 * i] = theta[2 * own_rows[i]];
                                    shift[2 * i + 1] = theta[2 * own_rows[i] + 1];
                                }
                            else
                                for (int64_t i = 0; i < n; ++i) {
                                    const int64_t *its = own_rows + i * n_cols;
                                    double a = theta[2 * its[0]], b = theta[2 * its[0] + 1];
                                    for (int64_t col = 1; col < n_cols; ++col) {
                                        a = a + theta[2 * its[col]];
                                        b = b + theta[2 * its[col] + 1];
                                    }
                                    shift[2 * i] = a;
                                    shift[2 * i + 1] = b;
                                }
                        }
                        const double *shifts = param_index ? shift : theta;
                        const int64_t stride = param_index ? 2 : 0;
                        if (mode == 1) {
                            uint8_t *closed_own = closed + c * grid_h * grid_w;
                            if (!closed_done[c]) close3(grid_h, grid_w, own, closed_own, close_tmp);
                            closed_done[c] = 1;
                            own = closed_own;
                        }
                        const int64_t position = batch * batch_size + j;
                        /* the next configuration's rows, fetched while this one is projected */
                        prefetch_plan plan = {{0}, {0, 0, 0}, 0, 3};
                        if (position + 1 < batches * batch_size) {
                            const int64_t next = order[position + 1], first = offsets[next];
                            const int64_t count = offsets[next + 1] - first;
                            plan_range(&plan, 0, points + 3 * first, count * 3 * (int64_t)sizeof(double));
                            if (mode != 2) { /* group_crossing runs no chain: the points alone */
                                plan_range(&plan, 1, pixels32 + 2 * first, count * 2 * (int64_t)sizeof(int32_t));
                                plan_range(&plan, 2, rank32 + first, count * (int64_t)sizeof(int32_t));
                            }
                            plan.range = 0;
                        }
                        /* in pieces (elementwise: the same values as in one call), a few lines fetched after each */
                        const int64_t pieces = (n + PROJECT_PIECE - 1) / PROJECT_PIECE;
                        const int64_t per_piece =
                            pieces ? (plan.lines[0] + plan.lines[1] + plan.lines[2] + pieces - 1) / pieces : 0;
                        for (int64_t at = 0; at < n; at += PROJECT_PIECE) {
                            const int64_t m = n - at < PROJECT_PIECE ? n - at : PROJECT_PIECE;
#ifdef TRAIN_AVX2
                            if (wide)
                                project_avx2(m, points + 3 * (lo + at), shifts + stride * at, stride, fx, fy, cx, cy,
                                             rows_per_pixel, cols_per_pixel, screen_height, screen + 2 * at,
                                             projected + 2 * at);
                            else
#endif
                                project(m, points + 3 * (lo + at), shifts + stride * at, stride, fx, fy, cx, cy,
                                        rows_per_pixel, cols_per_pixel, screen_height, screen + 2 * at,
                                        projected + 2 * at);
                            prefetch_some(&plan, per_piece);
                        }
                        prefetch_some(&plan, INT64_MAX);
                        if (mode == 2) {
                            if (n_target[c] < 0) {
                                n_target[c] = count_active(grid_h * grid_w, own);
                            }
                            const int64_t mismatch = crossing_pull(
                                n, screen, projected, points + 3 * lo, config_group[c], config_group[c + 1], group_start,
                                members, own, height, width, k_row, k_col, crossing + 3 * li, cover, stamp,
                                padded_cells, n_target[c], known_pixels + 2 * lo, known_lower, known_mismatch + c,
                                own_rows, n_cols, grad);
                            sum_add(&loss, (double)mismatch);
                            continue;
                        }
                        const int64_t n_pulled = train_chain(
                            n, projected, pixels32 + 2 * lo, rank32 + lo, (int32_t)height, (int32_t)width, (int32_t)steps,
                            (int32_t)level, table, sentinel, own, (int32_t)grid_h, (int32_t)grid_w, current, block,
                            landing, cell, alive, pulled);
                        for (int64_t k = 0; k < n_pulled; ++k) { /* in point order, as before: the loss's order */
                            const int64_t i = pulled[k];
                            const int64_t centre_row = mode ? landing[2 * i] : block[2 * i];
                            const int64_t centre_col = mode ? landing[2 * i + 1] : block[2 * i + 1];
                            const int64_t skip = mode ? 4 : (landing[2 * i] - block[2 * i]) * 3 +
                                                                       (landing[2 * i + 1] - block[2 * i + 1]) + 4;
                            double pull[2], l1[2];
                            window_pull(screen[2 * i], screen[2 * i + 1], centre_row, centre_col, skip, own, grid_h,
                                        grid_w, block_size, pull, l1);
                            for (int64_t col = 0; col < row_cols; ++col) { /* (row, col) -> (x, y) */
                                const int64_t row = own_rows ? own_rows[i * n_cols + col] : 0;
                                grad[2 * row] += pull[1];
                                grad[2 * row + 1] += pull[0];
                            }
                            const double z = points[3 * (lo + i) + 2] + 0.0;
                            sum_add(&loss, l1[0] * (z / k_row));
                            sum_add(&loss, l1[1] * (z / k_col));
                        }
                    }
                    int finite = 1;
                    for (int64_t m = 0; m < n_moved; ++m) { /* theta = theta - rate * grad on the moved rows */
                        const int64_t row = moved_rows[m];
                        const double own_rate = row_rate ? rate * row_rate[row] : rate;
                        const double move_a = own_rate * grad[2 * row], move_b = own_rate * grad[2 * row + 1];
                        theta[2 * row] = theta[2 * row] - move_a;
                        theta[2 * row + 1] = theta[2 * row + 1] - move_b;
                        finite &= isfinite(theta[2 * row]) && isfinite(theta[2 * row + 1]);
                        grad[2 * row] = grad[2 * row + 1] = 0.0;
                        row_moved[row] = 0;
                    }
                    losses[step * n_runs + run] = loss.sum + loss.compensation;
                    if ((step + 1) % record_every == 0 || !finite) {
                        double *record = thetas + (((step + record_every) / record_every) * n_runs + run) * run_size;
                        for (int64_t k = 0; k < run_size; ++k) record[k] = theta[k];
                    }
                    if (!finite) {
                        failed[run] = step;
                        break;
                    }
                    ++step;
                }
            }
        }
    }
done:
    free(dense), free(screen), free(rows), free(cell_min), free(pulled), free(alive), free(pixels32), free(rank32);
    free(cover), free(stamp), free(n_target), free(known_pixels), free(known_lower), free(known_mismatch);
    free(closed_done), free(close_tmp), free(theta), free(grad), free(moved_rows), free(row_moved), free(shift);
    free(config_rows), free(row_list), free(row_stamp);
    return code;
}

#ifdef TRAIN_AVX2
__attribute__((target("avx2"))) static int64_t train_avx2(TRAIN_PARAMETERS) { return train_body(TRAIN_ARGUMENTS, 1); }
#endif
static int64_t train_plain(TRAIN_PARAMETERS) { return train_body(TRAIN_ARGUMENTS, 0); }

int64_t sdm_train(TRAIN_PARAMETERS) {
#ifdef TRAIN_AVX2
    if (__builtin_cpu_supports("avx2")) return train_avx2(TRAIN_ARGUMENTS);
#endif
    return train_plain(TRAIN_ARGUMENTS);
}

/* ---- the noise of the paired runs (sdm.sky.add_target_noise into a NoiseBuffer) ----
 *
 * Every active pixel moved by its drawn move, written into a reused 0/1 buffer: first the n_written entries
 * the last draw set are cleared (the buffer is all 0 again), then each moved pixel on its grid is set and its
 * flat index listed in `written` (capacity n). Setting a byte is idempotent, so the order does not matter.
 *
 * active:       (n, n_lead + 2) leading indices then (row, col) of each active pixel
 * lead_strides: (n_lead,) the buffer's strides of the leading dimensions (bytes = elements: bool)
 * moves:        (n, 2) the drawn (row, col) moves
 * out:          the buffer, height x width planes; written: (n,) in: the last draw's flat indices, out: this one's
 * Returns the number of pixels set (this draw's n_written).
 */
int64_t sdm_noise_fill(int64_t n, const int64_t *active, int64_t n_lead, const int64_t *lead_strides,
                       const int64_t *moves, int64_t height, int64_t width, uint8_t *out, int64_t *written,
                       int64_t n_written) {
    for (int64_t k = 0; k < n_written; ++k) out[written[k]] = 0;
    const int64_t columns = n_lead + 2;
    int64_t count = 0;
    for (int64_t i = 0; i < n; ++i) {
        const int64_t *pixel = active + i * columns;
        const int64_t row = pixel[n_lead] + moves[2 * i], col = pixel[n_lead + 1] + moves[2 * i + 1];
        if (!on_grid(row, col, height, width)) continue;
        int64_t flat = row * width + col;
        for (int64_t d = 0; d < n_lead; ++d) flat += pixel[d] * lead_strides[d];
        out[flat] = 1;
        written[count++] = flat;
    }
    return count;
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
 * memo:         the last counts of this table, L = n_slots >= K slots (sdm.baselines.cmaes.MismatchMemo):
 *               slot_offsets (L * G,) int64 a candidate's group shifts per slot, slot_sums (L * N,) int64
 *               its per-configuration sums (FP - TP), state (L + 1,) int64 each slot's validity, then the
 *               next slot to fill (all zero at first). This call's candidates take the K slots from the next
 *               one on (their shifts are computed there); a configuration whose groups all shift as in a
 *               valid slot's candidate (or an earlier candidate of this call) takes that sum: the count
 *               depends on the group shifts alone, so it is the same integer. Near CMA-ES's convergence
 *               most configurations of a candidate shift as in its neighbours' (in one floor search at
 *               noise level 2, 6 slots spared 82% of the passes over points; the floor's searches ran
 *               2.4x faster).
 * stamp:        (cells_per_config + 1,) uint32 scratch, its last entry the last stamp used (all zero at
 *               first, then only ever written here)
 * counts:       (K,) out, false positives + false negatives, or -1
 */
/* Whether the groups lo..hi-1 shift alike in two candidates' shifts. */
static inline int same_shifts(const int64_t *restrict one, const int64_t *restrict other, int64_t lo, int64_t hi) {
    for (int64_t g = lo; g < hi; ++g)
        if (one[g] != other[g]) return 0;
    return 1;
}

void sdm_pixel_mismatch(int64_t n_candidates, const double *theta, int64_t n_groups, int64_t n_configs,
                        const double *gain, const double *frac_bounds, const double *shift_low,
                        const double *shift_high, const int64_t *group_start, const int64_t *config_group,
                        const int32_t *cells, const int8_t *table, int64_t cells_per_config, int64_t padded_width,
                        const double *limits, int64_t n_target, int64_t n_slots, int64_t *slot_offsets,
                        int64_t *slot_sums, int64_t *state, uint32_t *stamp, int64_t *counts) {
    const double *frac_high = frac_bounds + 2 * n_groups;
    const double max_gain_row = limits[0], max_gain_col = limits[1], exact_range = limits[2];
    int64_t *valid = state, next = state[n_slots];
    for (int64_t k = 0; k < n_candidates; ++k) valid[(next + k) % n_slots] = 0; /* rewritten below */
    for (int64_t k = 0; k < n_candidates; ++k) {
        const double a = theta[2 * k], b = theta[2 * k + 1];
        counts[k] = -1;
        /* as ShiftLayout.rendered_ids: non-finite or too far, then every group's bounds */
        if (!(a - a == 0.0 && b - b == 0.0) || __builtin_fabs(b) * max_gain_row > exact_range ||
            __builtin_fabs(a) * max_gain_col > exact_range)
            continue;
        int64_t *offset = slot_offsets + ((next + k) % n_slots) * n_groups;
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
        const int64_t g_lo = config_group[c], g_hi = config_group[c + 1];
        for (int64_t k = 0; k < n_candidates; ++k) {
            if (counts[k] < 0) continue;
            const int64_t slot = (next + k) % n_slots;
            const int64_t *offset = slot_offsets + slot * n_groups;
            int64_t known = -1; /* a slot whose candidate shifts this configuration's groups alike */
            for (int64_t j = 0; j < k && known < 0; ++j) /* this call's earlier candidates */
                if (counts[j] >= 0 && same_shifts(offset, slot_offsets + ((next + j) % n_slots) * n_groups, g_lo, g_hi))
                    known = (next + j) % n_slots;
            for (int64_t other = 0; other < n_slots && known < 0; ++other) /* the earlier calls' */
                if (valid[other] && same_shifts(offset, slot_offsets + other * n_groups, g_lo, g_hi)) known = other;
            int64_t sum = 0;
            if (known >= 0) {
                sum = slot_sums[known * n_configs + c];
            } else {
                const uint32_t mark = ++last;
                for (int64_t g = g_lo; g < g_hi; ++g) {
                    const int64_t shift = offset[g];
                    for (int64_t p = group_start[g]; p < group_start[g + 1]; ++p) {
                        const int64_t id = (int64_t)cells[p] + shift;
                        if (stamp[id] != mark) { /* a pixel covered twice counts once (rare: well predicted) */
                            stamp[id] = mark;
                            sum += (int64_t)weights[id] - 1;
                        }
                    }
                }
            }
            slot_sums[slot * n_configs + c] = sum;
            counts[k] += sum;
        }
    }
    stamp[cells_per_config] = last;
    for (int64_t k = 0; k < n_candidates; ++k) valid[(next + k) % n_slots] = counts[k] >= 0;
    state[n_slots] = (next + n_candidates) % n_slots;
}
