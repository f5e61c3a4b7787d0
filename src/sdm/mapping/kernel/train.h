/* The trainer (sdm_train, train.c) across its files: its limits, one call's arguments and working memory
 * (train_setup.c), and crossing.c's flow. Its loops over points (train_points.h) and targets (targets.h) are
 * static and included by train.c alone: they are compiled into each of its copies per instruction set.
 */
#ifndef SDM_TRAIN_H
#define SDM_TRAIN_H

#include "kernel.h"

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
/* The pixels off the screen, on each side, whose coverage group_crossing counts (crossing.c). */
#define CROSSING_MARGIN 2

int64_t sdm_train(int64_t n_runs, int64_t n_configs, const int64_t *offsets, const double *points,
                  const int64_t *pixels, const int64_t *rank, int64_t height, int64_t width, const double *camera,
                  int64_t steps, int64_t n_levels, int64_t n_epoch, int64_t batch_size, const int64_t *levels,
                  const double *rates, const uint8_t *modes, const int64_t *config_group, const int64_t *group_start,
                  const int32_t *members, const double *crossing, const int64_t *orders, const int64_t *targets,
                  const int64_t *bases, uint8_t *pyramid, int64_t no_rank, int64_t n_rows, int64_t n_cols,
                  const int64_t *param_index, const double *row_rate, int64_t record_every, const double *theta0,
                  double *thetas, double *losses, int64_t *failed);

/* sdm_train's arguments (train.c documents them), in its parameters' order; no_rank is not read (the trainer's
 * rmin tables hold NO_RANK32). */
typedef struct {
    int64_t n_runs, n_configs;
    const int64_t *offsets;
    const double *points;
    const int64_t *pixels, *rank;
    int64_t height, width;
    const double *camera;
    int64_t steps, n_levels, n_epoch, batch_size;
    const int64_t *levels;
    const double *rates;
    const uint8_t *modes;
    const int64_t *config_group, *group_start;
    const int32_t *members;
    const double *crossing;
    const int64_t *orders, *targets, *bases;
    uint8_t *pyramid;
    int64_t no_rank, n_rows, n_cols;
    const int64_t *param_index;
    const double *row_rate;
    int64_t record_every;
    const double *theta0;
    double *thetas, *losses;
    int64_t *failed;
} train_call;

/* One call's working memory (train_allocate), shared by its runs. */
typedef struct {
    /* the set's pixels (clamped: start_pixel) and ranks (ranks_in_int32) in int32: the chain reads a third
     * fewer bytes per point than from the int64 rows */
    int32_t *pixels32, *rank32;
    /* one configuration's working rows (`largest` points at most): the projection, its floor and the chain's */
    int64_t largest;
    double *screen;
    int32_t *rows, *projected, *current, *block, *landing, *cell, *pulled;
    uint8_t *alive;
    /* the chain's two rmin tables of sentinel + 1 cells each (sentinel: the screen's cells) */
    int32_t *cell_min, *table[2], sentinel;
    /* group_crossing's pixel counts and stamps (padded_cells + 1), each configuration's active target pixels
     * (-1: not yet counted; per run: its level-0 target), and its last pixels, lowered changes and mismatch in
     * this run (crossing_pull); NULL without mode 2 */
    int64_t padded_cells;
    int32_t *cover, *known_pixels, *known_lower;
    uint32_t *stamp;
    int64_t *n_target, *known_mismatch;
    /* the rows: a run's theta, a batch's summed flow per row, the rows it moved, each point's shift (with
     * param_index) */
    double *theta, *grad, *shift;
    int64_t *moved_rows;
    uint8_t *row_moved;
    /* each configuration's distinct rows, row_list[config_rows[c] .. config_rows[c + 1]] (with param_index): a
     * step marks its configurations' rows, not every point's */
    int64_t *config_rows, *row_list, *row_stamp;
    /* closed_centred_r1's closed targets: which configurations' `closed` holds (mode 1), close3's scratch */
    uint8_t *closed_done, *close_tmp, *closed;
    /* where the zoomed-out levels 1..steps of a run's pyramid lie in `pyramid` */
    int64_t level_start[64];
} train_space;

/* train_setup.c: sdm_train's -2 and -3 (0: the call can run), its working memory (0: none could be had; freed by
 * train_free either way). */
KERNEL_INTERNAL int64_t train_check(const train_call *call);
KERNEL_INTERNAL int train_allocate(const train_call *call, train_space *space);
KERNEL_INTERNAL void train_free(train_space *space);

/* crossing.c: one configuration's group_crossing flow and mismatch. */
KERNEL_INTERNAL int64_t crossing_pull(int64_t n, const double *restrict screen, const int32_t *restrict projected,
                                      const double *restrict q, int64_t g_lo, int64_t g_hi,
                                      const int64_t *restrict group_start, const int32_t *restrict members,
                                      const uint8_t *restrict target, int64_t height, int64_t width, double k_row,
                                      double k_col, const double *crossing, int32_t *restrict cover,
                                      uint32_t *restrict stamp, int64_t padded_cells, int64_t n_target,
                                      int32_t *restrict known_pixels, int32_t *restrict lower,
                                      int64_t *known_mismatch, const int64_t *rows, int64_t n_cols, double *grad);

#endif
