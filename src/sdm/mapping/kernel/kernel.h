/* The compiled CPU kernel: what its files share (sdm/mapping/build.py builds them into one library).
 *
 * Its exported functions, each the exact counterpart of a torch formulation (sdm/mapping/native.py and the
 * bindings name them):
 *   sdm_chain          (chain.c)    <-> the level loop of sdm.mapping.fast.fast_mapping
 *   sdm_paper_flow     (chain.c)    <-> sdm.mapping.flow.dynamic_flow (the paper's eq. 19)
 *   sdm_train          (train.c)    <-> sdm.train.train_runs on the torch path (projection, chain, flow, SGD),
 *                                       for the paper's rule, "closed_centred_r1" and group_crossing
 *   sdm_noise_fill     (noise.c)    <-> sdm.sky.add_target_noise's scatter into a reused buffer
 *   sdm_pixel_mismatch (mismatch.c) <-> the CMA-ES baseline's exact count (sdm.experiments.baselines.mismatch)
 * They do the same integer arithmetic and, for the floating-point values, the same operations in the same
 * order, so their results equal the torch path's bit for bit (tests/mapping/test_native.py holds it); only
 * sdm_train's loss is summed in another order (train.c). Built with -ffp-contract=off: no fused
 * multiply-adds.
 *
 * Speed without changing a bit: built with -O3, so loops are vectorised, but a float loop only
 * elementwise: without -ffast-math (-fassociative-math) the compiler never reorders float operations, and
 * a vector lane of add, multiply, divide or floor rounds exactly as its scalar form (IEEE: each correctly
 * rounded). Sums over points whose order matters stay scalar loops: the loss (compensated) and the flow
 * (integers, exact in any order anyway). All the freedom is taken in the integer work (train.c).
 *
 * All arrays are C-contiguous; int64 for integers, uint8 (0/1) for bool, double for floats. The helpers
 * below are static inline: every file that calls one compiles it into its own loops.
 */
#ifndef SDM_KERNEL_H
#define SDM_KERNEL_H

#include <math.h>
#include <stdint.h>
#include <stdlib.h>

/* A function one file of the kernel defines for another: not exported from the library. */
#define KERNEL_INTERNAL __attribute__((visibility("hidden")))
/* A helper inlined wherever it is called, also into the trainer's AVX2 copy (compiled with its instructions). */
#define ALWAYS_INLINE inline __attribute__((always_inline))

static inline int64_t clamp_unit(int64_t value) { return value < -1 ? -1 : (value > 1 ? 1 : value); }

/* a - b wrapping around as torch's int64 subtraction does (defined in C where a signed subtraction is not): a
 * projection floored from NaN or beyond int64 is INT64_MIN, as torch's .long() gives it, and the step towards it
 * must be torch's. */
static inline int64_t wrapping_sub(int64_t a, int64_t b) { return (int64_t)((uint64_t)a - (uint64_t)b); }

static inline int on_grid(int64_t row, int64_t col, int64_t height, int64_t width) {
    return row >= 0 && row < height && col >= 0 && col < width;
}

static inline double sign_of(double value) { return (double)((value > 0.0) - (value < 0.0)); }

/* The 3x3 window of one pulled point: the one formulation of "which blocks pull, and how" (the paper's flow,
 * sdm_paper_flow, and the trainer's flows).
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

/* The exported functions (each file documents its own; build.py's SIGNATURES binds them). */
int64_t sdm_chain(int64_t n_points, const int64_t *projected, const int64_t *pixels, const int64_t *config,
                  const int64_t *rank, int64_t height, int64_t width, int64_t steps, int64_t zoom, int64_t *cell_min,
                  int64_t n_scratch, int64_t no_rank, int64_t *out_pixels, uint8_t *entered, uint8_t *landed,
                  int64_t *block_out, int64_t *landing_out, int64_t *current, int64_t *cell, uint8_t *alive);
int64_t sdm_paper_flow(int64_t n_points, const double *screen, const int64_t *config, const uint8_t *landed,
                       const int64_t *block, const int64_t *landing, const uint8_t *target, int64_t n_configs,
                       int64_t grid_h, int64_t grid_w, int64_t zoom, uint8_t *matched, double *flow,
                       int64_t *pulled, double *window_l1);
int64_t sdm_noise_fill(int64_t n, const int64_t *active, int64_t n_lead, const int64_t *lead_strides,
                       const int64_t *moves, int64_t height, int64_t width, uint8_t *out, int64_t *written,
                       int64_t n_written);
void sdm_pixel_mismatch(int64_t n_candidates, const double *theta, int64_t n_groups, int64_t n_configs,
                        const double *gain, const double *frac_bounds, const double *shift_low,
                        const double *shift_high, const int64_t *group_start, const int64_t *config_group,
                        const int32_t *cells, const int8_t *table, int64_t cells_per_config, int64_t padded_width,
                        const double *limits, int64_t n_target, int64_t n_slots, int64_t *slot_offsets,
                        int64_t *slot_sums, int64_t *state, uint32_t *stamp, int64_t *counts);
/* sdm_train's prototype is train.h's (its parameter list, TRAIN_PARAMETERS, is shared by its files). */

#endif
