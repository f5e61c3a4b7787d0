/* group_crossing at zoom 0 in the trainer (sdm.mapping.crossing.group_crossing_flow; sdm_train's mode 2).
 *
 * One configuration's flow summed into (grad_a, grad_b) and its exact pixel mismatch, from its n points'
 * projections (screen, and their floors in `projected`, as train_points.h's project() leaves them). The points
 * are grouped rigidly (crossing.rigid_groups: one configuration, one depth): group g lists its points' indices
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
#include "train.h"

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
int64_t crossing_pull(int64_t n, const double *restrict screen, const int32_t *restrict projected,
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
