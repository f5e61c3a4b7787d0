/* What a call of sdm_train checks and prepares before its runs: its refusals (-2, -3), its working memory, the
 * set's rows in int32 and each configuration's rows of theta (train.c runs the steps).
 */
#include "targets.h"
#include "train.h"

int64_t train_check(const train_call *call) {
    if (call->height > TRAIN_MAX_SIDE || call->width > TRAIN_MAX_SIDE ||
        call->height * call->width >= TRAIN_MAX_CELLS || call->steps > 62)
        return -2;
    for (int64_t li = 0; li < call->n_levels; ++li) {
        const int64_t level = call->levels[li];
        if (level < 0 || level > call->steps || (call->modes[li] == 2 && level != 0)) return -3;
    }
    return 0;
}

static int compare_pairs(const void *left, const void *right) {
    const int64_t *l = left, *r = right;
    return (l[0] > r[0]) - (l[0] < r[0]);
}

/* The ranks into rank32 (P,). Ranks matter only by their order within a configuration (rmin keeps the lowest),
 * and the trainer's rmin tables hold int32: where every rank is in [0, INT32_MAX) they are copied as they are,
 * else each configuration's ranks are replaced by their position in its sorted order (equal ranks stay equal).
 * 0 where no memory could be had. */
static int ranks_in_int32(int64_t n_configs, const int64_t *offsets, const int64_t *rank, int32_t *rank32) {
    const int64_t n_points = offsets[n_configs];
    int fits = 1;
    for (int64_t i = 0; i < n_points; ++i) fits &= rank[i] >= 0 && rank[i] < NO_RANK32;
    if (fits) {
        for (int64_t i = 0; i < n_points; ++i) rank32[i] = (int32_t)rank[i];
        return 1;
    }
    int64_t *pairs = malloc(sizeof(int64_t) * 2 * (size_t)(n_points ? n_points : 1));
    if (!pairs) return 0;
    for (int64_t c = 0; c < n_configs; ++c) {
        const int64_t lo = offsets[c], n = offsets[c + 1] - lo;
        for (int64_t i = 0; i < n; ++i) pairs[2 * i] = rank[lo + i], pairs[2 * i + 1] = i;
        qsort(pairs, (size_t)n, 2 * sizeof(int64_t), compare_pairs);
        int32_t position = 0;
        for (int64_t i = 0; i < n; ++i) {
            if (i && pairs[2 * i] != pairs[2 * i - 2]) ++position;
            rank32[lo + pairs[2 * i + 1]] = position;
        }
    }
    free(pairs);
    return 1;
}

static inline int32_t start_pixel(int64_t pixel) {
    return (int32_t)(pixel < -PIXEL_LIMIT ? -PIXEL_LIMIT : (pixel > PIXEL_LIMIT ? PIXEL_LIMIT : pixel));
}

/* Each configuration's distinct rows of theta, listed once per call (one pass over the points, a stamp per
 * row). */
static void list_config_rows(const train_call *call, train_space *space) {
    const int64_t n_cols = call->n_cols, *offsets = call->offsets, *param_index = call->param_index;
    int64_t *config_rows = space->config_rows, *row_list = space->row_list, *row_stamp = space->row_stamp;
    for (int64_t k = 0; k < call->n_rows; ++k) row_stamp[k] = -1;
    config_rows[0] = 0;
    for (int64_t c = 0; c < call->n_configs; ++c) {
        int64_t listed = config_rows[c];
        for (int64_t j = offsets[c] * n_cols; j < offsets[c + 1] * n_cols; ++j)
            if (row_stamp[param_index[j]] != c) {
                row_stamp[param_index[j]] = c;
                row_list[listed++] = param_index[j];
            }
        config_rows[c + 1] = listed;
    }
}

/* The largest configuration's points, rounded up to 16 (at least 1 before): the working rows' length. */
static int64_t largest_configuration(int64_t n_configs, const int64_t *offsets) {
    int64_t largest = 1;
    for (int64_t c = 0; c < n_configs; ++c)
        if (offsets[c + 1] - offsets[c] > largest) largest = offsets[c + 1] - offsets[c];
    return (largest + 15) & ~(int64_t)15;
}

/* The memory of group_crossing (mode 2) and closed_centred_r1 (mode 1), where a level has that mode; 0 where none
 * could be had. */
static int allocate_modes(const train_call *call, train_space *space) {
    int crosses = 0, closes = 0;
    for (int64_t li = 0; li < call->n_levels; ++li) {
        crosses |= call->modes[li] == 2;
        closes |= call->modes[li] == 1;
    }
    const int64_t n_configs = call->n_configs, n_points = call->offsets[n_configs];
    const int64_t cells = call->height * call->width;
    space->padded_cells = (call->height + 2 * (CROSSING_MARGIN + 1)) * (call->width + 2 * (CROSSING_MARGIN + 1));
    if (crosses) {
        const int64_t n_groups = call->config_group[n_configs];
        space->cover = calloc((size_t)cells, sizeof(int32_t));
        space->stamp = calloc((size_t)(space->padded_cells + 1), sizeof(uint32_t));
        space->n_target = malloc(sizeof(int64_t) * (size_t)n_configs);
        space->known_pixels = malloc(sizeof(int32_t) * (size_t)(2 * n_points + 1));
        space->known_lower = malloc(sizeof(int32_t) * (size_t)(4 * n_groups + 1));
        space->known_mismatch = malloc(sizeof(int64_t) * (size_t)n_configs);
        if (!space->cover || !space->stamp || !space->n_target || !space->known_pixels || !space->known_lower ||
            !space->known_mismatch)
            return 0;
    }
    if (closes) {
        space->closed_done = malloc((size_t)n_configs);
        space->close_tmp = malloc((size_t)cells);
        if (!space->closed_done || !space->close_tmp) return 0;
    }
    return 1;
}

/* The rows of theta: a run's theta, a batch's summed flow per row, the rows it moved and, with param_index,
 * each point's shift and each configuration's rows (list_config_rows); 0 where no memory could be had. */
static int allocate_rows(const train_call *call, train_space *space) {
    const int64_t n_rows = call->n_rows, n_configs = call->n_configs, n_points = call->offsets[n_configs];
    space->theta = malloc(sizeof(double) * (size_t)(2 * n_rows));
    space->grad = calloc((size_t)(2 * n_rows), sizeof(double));
    space->moved_rows = malloc(sizeof(int64_t) * (size_t)(n_rows + 1));
    space->row_moved = calloc((size_t)n_rows + 1, 1);
    if (!space->theta || !space->grad || !space->moved_rows || !space->row_moved) return 0;
    if (!call->param_index) return 1;
    space->shift = malloc(sizeof(double) * (size_t)space->largest * 2);
    space->config_rows = malloc(sizeof(int64_t) * (size_t)(n_configs + 1));
    space->row_list = malloc(sizeof(int64_t) * (size_t)(n_points * call->n_cols + 1));
    space->row_stamp = malloc(sizeof(int64_t) * (size_t)(n_rows + 1));
    if (!space->shift || !space->config_rows || !space->row_list || !space->row_stamp) return 0;
    list_config_rows(call, space);
    return 1;
}

/* The set's points in the layout the chain reads (int32), one configuration's working rows and the rmin
 * tables (every cell NO_RANK32); 0 where no memory could be had. */
static int allocate_points(const train_call *call, train_space *space) {
    const int64_t n_points = call->offsets[call->n_configs], largest = space->largest;
    const int32_t cells = (int32_t)(call->height * call->width);
    space->pixels32 = malloc(sizeof(int32_t) * (size_t)(2 * n_points + 1));
    space->rank32 = malloc(sizeof(int32_t) * (size_t)(n_points + 1));
    space->screen = malloc(sizeof(double) * (size_t)largest * 2);
    space->rows = malloc(sizeof(int32_t) * (size_t)largest * 9);
    space->alive = malloc((size_t)largest);
    space->cell_min = malloc(sizeof(int32_t) * (size_t)(2 * (cells + 1)));
    space->pulled = malloc(sizeof(int32_t) * (size_t)largest);
    if (!space->pixels32 || !space->rank32 || !space->screen || !space->rows || !space->alive || !space->cell_min ||
        !space->pulled)
        return 0;
    if (!ranks_in_int32(call->n_configs, call->offsets, call->rank, space->rank32)) return 0;
    for (int64_t j = 0; j < 2 * n_points; ++j) space->pixels32[j] = start_pixel(call->pixels[j]);
    int32_t *rows = space->rows;
    space->projected = rows, space->current = rows + 2 * largest, space->block = rows + 4 * largest;
    space->landing = rows + 6 * largest, space->cell = rows + 8 * largest;
    for (int64_t i = 0; i < 2 * (cells + 1); ++i) space->cell_min[i] = NO_RANK32;
    space->table[0] = space->cell_min, space->table[1] = space->cell_min + cells + 1;
    space->sentinel = cells;
    return 1;
}

int train_allocate(const train_call *call, train_space *space) {
    *space = (train_space){0};
    space->largest = largest_configuration(call->n_configs, call->offsets);
    /* where the zoomed-out levels 1..steps of a run's pyramid lie in `pyramid`, then the closed targets */
    for (int64_t k = 2; k <= call->steps + 1; ++k)
        space->level_start[k] =
            space->level_start[k - 1] + call->n_configs * (call->height >> (k - 1)) * (call->width >> (k - 1));
    const int zooms = zooms_any(call->n_runs, call->n_levels, call->targets, call->levels);
    space->closed = call->pyramid + (zooms ? space->level_start[call->steps + 1] : 0);
    return allocate_points(call, space) && allocate_rows(call, space) && allocate_modes(call, space);
}

void train_free(train_space *space) {
    free(space->pixels32), free(space->rank32), free(space->screen), free(space->rows), free(space->alive);
    free(space->cell_min), free(space->pulled), free(space->cover), free(space->stamp), free(space->n_target);
    free(space->known_pixels), free(space->known_lower), free(space->known_mismatch), free(space->theta);
    free(space->grad), free(space->moved_rows), free(space->row_moved), free(space->shift), free(space->config_rows);
    free(space->row_list), free(space->row_stamp), free(space->closed_done), free(space->close_tmp);
}
