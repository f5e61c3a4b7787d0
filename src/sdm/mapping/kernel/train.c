/* sdm_train: R whole training runs (sdm.train.train_runs): every level, epoch, mini-batch, chain, flow, loss and
 * SGD step, run after run (runs never interact, so each keeps its own targets hot in the cache).
 *
 * Data, shared by the runs (the packed ConfigurationSet, C-contiguous):
 *   offsets (N + 1,) row offsets; points (P, 3) q in metres; pixels (P, 2); rank (P,) rmin priority
 * camera:  fx, fy, cx, cy, rows_per_image_pixel, cols_per_image_pixel, fy * rows_per_image_pixel,
 *          fx * cols_per_image_pixel (the last two: metres per screen pixel are depth / them)
 * Levels:  levels (n_levels,) the loss level of each entry, one after another (each in 0..steps; the chain
 *          always starts at steps); rates (n_levels,) the learning rate of each; modes (n_levels,) the
 *          flow of each: 0 the paper's, 1 the closed_centred_r1 window (centred on the landing block, on the
 *          level's target closed by close3 (targets.c): the kernel closes each configuration's the first time a run
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
 *          row_rate (L, K): each row's factor on loss level li's rate (NULL: 1 for every row at every level).
 * theta0:  (R, K, 2) starts (a, b), metres
 * Outputs: thetas (total / record_every + 1, R, K, 2) theta before the first step and after every
 *          record_every-th step; losses (total, R); failed (R,) the step (0-based) at which run r's theta
 *          became non-finite (the run stops there; later entries unwritten), -1 where it did not.
 *
 * A step of run r: point = q + (a, b, 0), (a, b) its rows' sum; the projection as sdm.camera.Camera.project
 * evaluates it (same operations, same order: project); the chain per configuration (train_chain: chain.c's
 * chain_level's integer arithmetic in int32); the flow by window_pull; grad = the summed flow per row (integers:
 * exact in any order); theta = theta - rate * grad (two roundings, as torch's theta -= rate * theta.grad) on
 * the rows the batch's points move (the others' grad is 0: theta - rate * 0 is theta, as torch's step leaves
 * them). A batch without points pulls nothing. At a mode-2 level the flow and loss are crossing_pull's
 * (crossing.c; the loss: the mismatched pixels, summed exactly).
 * The loss is the sum over the pulled points of l1_row * (z / k_row) + l1_col * (z / k_col), the
 * products as sdm.mapping.flow.pull_loss forms them, the sum compensated in point order (torch's
 * .sum() adds in its own order, which is not reproduced: the two agree to the last bits,
 * tests/mapping/test_native.py holds them to 1e-12 relative). Theta never depends on the loss.
 * Returns 0, -1 where no memory could be had, -2 for a screen beyond the int32 chain (TRAIN_MAX_SIDE), or -3
 * for a level outside 0..steps or a mode-2 level above 0.
 *
 * Speed without changing a bit (kernel.h): all the freedom is taken in the integer work. The chain runs in
 * int32 lanes, its loops split so that the per-coordinate arithmetic vectorises apart from the rmin tables'
 * gathers and scatters (train_points.h). The runs are compiled twice in one library, plain x86-64 and AVX2,
 * and sdm_train picks at run time by the CPU (__builtin_cpu_supports): the cached library is the same on every
 * x86-64, so the cache key needs no -march. Every function below from a run down to one configuration is
 * always_inline: each copy is one loop nest, specialised to its instruction set.
 */
#include "targets.h"
#include "train.h"
#include "train_points.h"

/* Points projected per piece between prefetches (even: AVX2's pairs cover every piece but the last). */
#define PROJECT_PIECE 32

/* One loss level of a run: what its steps read. */
typedef struct {
    int64_t li, level, grid_h, grid_w;
    const uint8_t *target; /* (N, grid_h, grid_w) 0/1 */
    double rate, block_size;
    int mode;
} level_setting;

/* One run's own state: its index and step, its level-0 target and the targets whose configurations' active
 * pixels (n_target) and closings (closed_done) the working memory holds. */
typedef struct {
    int64_t run, step;
    const uint8_t *base, *counted, *closing;
} run_state;

/* Configuration c's rows marked moved (moved_rows, *n_moved) and each of its n points' shift: its rows of
 * theta (own_rows) summed in column order, as torch sums them. */
static ALWAYS_INLINE void point_shifts(const train_call *call, train_space *space, int64_t c, int64_t n,
                                       const int64_t *own_rows, int64_t *n_moved) {
    const int64_t n_cols = call->n_cols, *config_rows = space->config_rows, *row_list = space->row_list;
    const double *theta = space->theta;
    double *shift = space->shift;
    int64_t *moved_rows = space->moved_rows, moved = *n_moved;
    uint8_t *row_moved = space->row_moved;
    for (int64_t k = config_rows[c]; k < config_rows[c + 1]; ++k)
        if (!row_moved[row_list[k]]) {
            row_moved[row_list[k]] = 1;
            moved_rows[moved++] = row_list[k];
        }
    *n_moved = moved;
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

/* The projection of configuration order[position]'s n points (from row lo) into screen and projected, in
 * pieces (elementwise: the same values as in one call), a few lines of the next configuration's rows fetched
 * after each (prefetch_plan): its points, and where a chain follows (mode 0, 1) its pixels and ranks. */
static ALWAYS_INLINE void project_configuration(const train_call *call, train_space *space, int mode,
                                                const int64_t *order, int64_t position, int64_t lo, int64_t n,
                                                int wide) {
    const double *camera = call->camera, *points = call->points;
    const double fx = camera[0], fy = camera[1], cx = camera[2], cy = camera[3];
    const double rows_per_pixel = camera[4], cols_per_pixel = camera[5], screen_height = (double)call->height;
    const int64_t *offsets = call->offsets, stride = call->param_index ? 2 : 0;
    const double *shifts = call->param_index ? space->shift : space->theta;
    double *screen = space->screen;
    int32_t *projected = space->projected;
    prefetch_plan plan = {{0}, {0, 0, 0}, 0, 3};
    if (position + 1 < (call->n_configs / call->batch_size) * call->batch_size) {
        const int64_t next = order[position + 1], first = offsets[next];
        const int64_t count = offsets[next + 1] - first;
        plan_range(&plan, 0, points + 3 * first, count * 3 * (int64_t)sizeof(double));
        if (mode != 2) { /* group_crossing runs no chain: the points alone */
            plan_range(&plan, 1, space->pixels32 + 2 * first, count * 2 * (int64_t)sizeof(int32_t));
            plan_range(&plan, 2, space->rank32 + first, count * (int64_t)sizeof(int32_t));
        }
        plan.range = 0;
    }
    const int64_t pieces = (n + PROJECT_PIECE - 1) / PROJECT_PIECE;
    const int64_t per_piece = pieces ? (plan.lines[0] + plan.lines[1] + plan.lines[2] + pieces - 1) / pieces : 0;
    for (int64_t at = 0; at < n; at += PROJECT_PIECE) {
        const int64_t m = n - at < PROJECT_PIECE ? n - at : PROJECT_PIECE;
#ifdef TRAIN_AVX2
        if (wide)
            project_avx2(m, points + 3 * (lo + at), shifts + stride * at, stride, fx, fy, cx, cy, rows_per_pixel,
                         cols_per_pixel, screen_height, screen + 2 * at, projected + 2 * at);
        else
#endif
            project(m, points + 3 * (lo + at), shifts + stride * at, stride, fx, fy, cx, cy, rows_per_pixel,
                    cols_per_pixel, screen_height, screen + 2 * at, projected + 2 * at);
        prefetch_some(&plan, per_piece);
    }
    prefetch_some(&plan, INT64_MAX);
}

/* The flow of the n_pulled points the chain listed (pulled, in point order: the loss's order) into grad, summed
 * over each point's rows (own_rows; NULL: row 0), and their loss into *loss: the paper's window (mode 0,
 * centred on the input block) or closed_centred_r1's (mode 1, on the landing block), on the configuration's
 * target `own`; lo: its first point's row. */
static ALWAYS_INLINE void pull_points(const train_call *call, const train_space *space, const level_setting *setting,
                                      const uint8_t *own, int64_t lo, int64_t n_pulled, const int64_t *own_rows,
                                      exact_sum *loss) {
    const int mode = setting->mode;
    const int64_t grid_h = setting->grid_h, grid_w = setting->grid_w, n_cols = call->n_cols;
    const int64_t row_cols = call->param_index ? n_cols : 1;
    const double block_size = setting->block_size, k_row = call->camera[6], k_col = call->camera[7];
    const double *points = call->points, *screen = space->screen;
    const int32_t *pulled = space->pulled, *block = space->block, *landing = space->landing;
    double *grad = space->grad;
    for (int64_t k = 0; k < n_pulled; ++k) {
        const int64_t i = pulled[k];
        const int64_t centre_row = mode ? landing[2 * i] : block[2 * i];
        const int64_t centre_col = mode ? landing[2 * i + 1] : block[2 * i + 1];
        const int64_t skip =
            mode ? 4 : (landing[2 * i] - block[2 * i]) * 3 + (landing[2 * i + 1] - block[2 * i + 1]) + 4;
        double pull[2], l1[2];
        window_pull(screen[2 * i], screen[2 * i + 1], centre_row, centre_col, skip, own, grid_h, grid_w, block_size,
                    pull, l1);
        for (int64_t col = 0; col < row_cols; ++col) { /* (row, col) -> (x, y) */
            const int64_t row = own_rows ? own_rows[i * n_cols + col] : 0;
            grad[2 * row] += pull[1];
            grad[2 * row + 1] += pull[0];
        }
        const double z = points[3 * (lo + i) + 2] + 0.0;
        sum_add(loss, l1[0] * (z / k_row));
        sum_add(loss, l1[1] * (z / k_col));
    }
}

/* group_crossing's flow (mode 2) of configuration c's n points, projected, into grad and its mismatch into
 * *loss (crossing_pull); its target's active pixels counted the first time the run needs them. */
static ALWAYS_INLINE void crossing_points(const train_call *call, train_space *space, const level_setting *setting,
                                          const uint8_t *own, int64_t c, int64_t lo, int64_t n,
                                          const int64_t *own_rows, exact_sum *loss) {
    const int64_t grid_h = setting->grid_h, grid_w = setting->grid_w;
    int64_t *n_target = space->n_target;
    if (n_target[c] < 0) n_target[c] = count_active(grid_h * grid_w, own);
    const int64_t mismatch = crossing_pull(
        n, space->screen, space->projected, call->points + 3 * lo, call->config_group[c], call->config_group[c + 1],
        call->group_start, call->members, own, call->height, call->width, call->camera[6], call->camera[7],
        call->crossing + 3 * setting->li, space->cover, space->stamp, space->padded_cells, n_target[c],
        space->known_pixels + 2 * lo, space->known_lower, space->known_mismatch + c, own_rows, call->n_cols,
        space->grad);
    sum_add(loss, (double)mismatch);
}

/* Configuration order[position] in a step: its points' shifts, projection, chain and flow into grad, its loss
 * into *loss, its rows into moved_rows (*n_moved). */
static ALWAYS_INLINE void train_configuration(const train_call *call, train_space *space,
                                              const level_setting *setting, const int64_t *order, int64_t position,
                                              exact_sum *loss, int64_t *n_moved, int wide) {
    const int64_t c = order[position], lo = call->offsets[c], n = call->offsets[c + 1] - lo;
    const int64_t grid_h = setting->grid_h, grid_w = setting->grid_w;
    const int64_t *own_rows = call->param_index ? call->param_index + lo * call->n_cols : NULL;
    const uint8_t *own = setting->target + c * grid_h * grid_w;
    if (own_rows) point_shifts(call, space, c, n, own_rows, n_moved);
    if (setting->mode == 1) { /* the closed target, closed the first time the run needs it */
        uint8_t *closed_own = space->closed + c * grid_h * grid_w;
        if (!space->closed_done[c]) close3(grid_h, grid_w, own, closed_own, space->close_tmp);
        space->closed_done[c] = 1;
        own = closed_own;
    }
    project_configuration(call, space, setting->mode, order, position, lo, n, wide);
    if (setting->mode == 2) {
        crossing_points(call, space, setting, own, c, lo, n, own_rows, loss);
        return;
    }
    const int64_t n_pulled =
        train_chain(n, space->projected, space->pixels32 + 2 * lo, space->rank32 + lo, (int32_t)call->height,
                    (int32_t)call->width, (int32_t)call->steps, (int32_t)setting->level, space->table,
                    space->sentinel, own, (int32_t)grid_h, (int32_t)grid_w, space->current, space->block,
                    space->landing, space->cell, space->alive, space->pulled);
    pull_points(call, space, setting, own, lo, n_pulled, own_rows, loss);
}

/* theta = theta - rate * grad on the n_moved moved rows (each at its own rate where row_rate is given), their grad
 * and marks cleared; whether theta stayed finite. */
static ALWAYS_INLINE int sgd_update(const train_call *call, train_space *space, double rate, int64_t li,
                                    int64_t n_moved) {
    const double *row_rate = call->row_rate ? call->row_rate + li * call->n_rows : NULL;
    const int64_t *moved_rows = space->moved_rows;
    double *theta = space->theta, *grad = space->grad;
    uint8_t *row_moved = space->row_moved;
    int finite = 1;
    for (int64_t m = 0; m < n_moved; ++m) {
        const int64_t row = moved_rows[m];
        const double own_rate = row_rate ? rate * row_rate[row] : rate;
        const double move_a = own_rate * grad[2 * row], move_b = own_rate * grad[2 * row + 1];
        theta[2 * row] = theta[2 * row] - move_a;
        theta[2 * row + 1] = theta[2 * row + 1] - move_b;
        finite &= isfinite(theta[2 * row]) && isfinite(theta[2 * row + 1]);
        grad[2 * row] = grad[2 * row + 1] = 0.0;
        row_moved[row] = 0;
    }
    return finite;
}

/* One SGD step of a run: mini-batch `batch` of the epoch's order, its loss and, every record_every-th step or
 * where theta became non-finite, theta recorded; whether theta stayed finite. */
static ALWAYS_INLINE int train_step(const train_call *call, train_space *space, const level_setting *setting,
                                    const run_state *state, const int64_t *order, int64_t batch, int wide) {
    const int64_t batch_size = call->batch_size, run = state->run, step = state->step;
    exact_sum loss = {0.0, 0.0};
    int64_t n_moved = 0;
    if (!call->param_index) { /* the shared shift: row 0 moves every point */
        space->moved_rows[n_moved++] = 0;
        space->row_moved[0] = 1;
    }
    for (int64_t j = 0; j < batch_size; ++j)
        train_configuration(call, space, setting, order, batch * batch_size + j, &loss, &n_moved, wide);
    const int finite = sgd_update(call, space, setting->rate, setting->li, n_moved);
    const int64_t n_runs = call->n_runs, record_every = call->record_every, run_size = 2 * call->n_rows;
    call->losses[step * n_runs + run] = loss.sum + loss.compensation;
    if ((step + 1) % record_every == 0 || !finite) {
        double *record = call->thetas + (((step + record_every) / record_every) * n_runs + run) * run_size;
        for (int64_t k = 0; k < run_size; ++k) record[k] = space->theta[k];
    }
    return finite;
}

/* The run's steps at loss level li: every epoch, every mini-batch; stops where theta became non-finite (failed). */
static ALWAYS_INLINE void train_level(const train_call *call, train_space *space, run_state *state, int64_t li,
                                      int wide) {
    const int64_t run = state->run, n_configs = call->n_configs, level = call->levels[li];
    const int64_t given = call->targets[run * call->n_levels + li];
    level_setting setting = {li, level, call->height >> level, call->width >> level, NULL, call->rates[li],
                             (double)((int64_t)1 << level), call->modes[li]};
    setting.target = given ? (const uint8_t *)(intptr_t)given
                           : (level ? call->pyramid + space->level_start[level] : state->base);
    if (setting.mode == 2 && state->counted != setting.target) {
        for (int64_t c = 0; c < n_configs; ++c) space->n_target[c] = space->known_mismatch[c] = -1;
        state->counted = setting.target;
    }
    if (setting.mode == 1 && state->closing != setting.target) {
        for (int64_t c = 0; c < n_configs; ++c) space->closed_done[c] = 0;
        state->closing = setting.target;
    }
    const int64_t n_epoch = call->n_epoch, batches = n_configs / call->batch_size;
    for (int64_t epoch = 0; epoch < n_epoch; ++epoch) {
        const int64_t *order = call->orders + ((li * n_epoch + epoch) * call->n_runs + run) * n_configs;
        for (int64_t batch = 0; batch < batches; ++batch) {
            if (!train_step(call, space, &setting, state, order, batch, wide)) {
                call->failed[run] = state->step;
                return;
            }
            ++state->step;
        }
    }
}

/* Run `run`: theta from its start, its pyramid zoomed out where the kernel does it, then its levels in turn. */
static ALWAYS_INLINE void train_run(const train_call *call, train_space *space, int64_t run, int wide) {
    const int64_t run_size = 2 * call->n_rows, steps = call->steps, n_levels = call->n_levels;
    for (int64_t k = 0; k < run_size; ++k)
        call->thetas[run * run_size + k] = space->theta[k] = call->theta0[run * run_size + k];
    call->failed[run] = -1;
    run_state state = {run, 0, (const uint8_t *)(intptr_t)call->bases[run], NULL, NULL};
    const int64_t *level_start = space->level_start;
    uint8_t *pyramid = call->pyramid;
    const int zoom_run = zooms_any(1, n_levels, call->targets + run * n_levels, call->levels);
    for (int64_t k = 1; zoom_run && k <= steps; ++k)
        halve_targets(call->n_configs, call->height >> (k - 1), call->width >> (k - 1),
                      k == 1 ? state.base : pyramid + level_start[k - 1], pyramid + level_start[k]);
    for (int64_t li = 0; li < n_levels && call->failed[run] < 0; ++li) train_level(call, space, &state, li, wide);
}

#ifdef TRAIN_AVX2
__attribute__((target("avx2"))) static void train_avx2(const train_call *call, train_space *space) {
    for (int64_t run = 0; run < call->n_runs; ++run) train_run(call, space, run, 1);
}
#endif
static void train_plain(const train_call *call, train_space *space) {
    for (int64_t run = 0; run < call->n_runs; ++run) train_run(call, space, run, 0);
}

int64_t sdm_train(int64_t n_runs, int64_t n_configs, const int64_t *offsets, const double *points,
                  const int64_t *pixels, const int64_t *rank, int64_t height, int64_t width, const double *camera,
                  int64_t steps, int64_t n_levels, int64_t n_epoch, int64_t batch_size, const int64_t *levels,
                  const double *rates, const uint8_t *modes, const int64_t *config_group, const int64_t *group_start,
                  const int32_t *members, const double *crossing, const int64_t *orders, const int64_t *targets,
                  const int64_t *bases, uint8_t *pyramid, int64_t no_rank, int64_t n_rows, int64_t n_cols,
                  const int64_t *param_index, const double *row_rate, int64_t record_every, const double *theta0,
                  double *thetas, double *losses, int64_t *failed) {
    const train_call call = {n_runs, n_configs, offsets, points, pixels, rank, height, width, camera, steps, n_levels,
                             n_epoch, batch_size, levels, rates, modes, config_group, group_start, members, crossing,
                             orders, targets, bases, pyramid, no_rank, n_rows, n_cols, param_index, row_rate,
                             record_every, theta0, thetas, losses, failed};
    int64_t code = train_check(&call);
    if (code) return code;
    train_space space;
    if (!train_allocate(&call, &space)) {
        code = -1;
    } else {
#ifdef TRAIN_AVX2
        if (__builtin_cpu_supports("avx2"))
            train_avx2(&call, &space);
        else
#endif
            train_plain(&call, &space);
    }
    train_free(&space);
    return code;
}
