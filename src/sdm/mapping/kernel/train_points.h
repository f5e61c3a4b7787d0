/* The trainer's loops over one configuration's points (included by train.c alone, compiled into each of its
 * copies): the projection (project, and two points per AVX2 register: project_avx2), the zoom chain in int32
 * (train_chain), the loss's compensated sum and the prefetches of the next configuration's rows.
 */
#ifndef SDM_TRAIN_POINTS_H
#define SDM_TRAIN_POINTS_H

#include "train.h"

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

/* Levels steps..zoom of the zoom chain for one configuration's n points: chain.c's chain_level's integer arithmetic
 * (the same shifts, clamp, steps and rmin), in int32 (exact: TRAIN_MAX_SIDE, PROJECTED_LIMIT) so that a vector
 * holds twice the lanes and the working rows half the cache. Each level in three loops, so that the one without
 * memory dependences vectorises: which points survived the level before (gathers from its rmin table, read and
 * reset as chain.c's rmin_survives), the step of every coordinate (the same operations on each of the 2n lanes:
 * vectorised), and the entries into this level's table (scatters). At the loss level nothing enters (the trainer
 * needs no rmin after it: landing is decided by the level before); instead the points that land on the grid in a
 * block the target leaves empty (the ones the flow pulls) are listed in `pulled`, in ascending order, by a
 * branchless append. The first level also prefetches the target block each point will most likely land in. Returns
 * the number pulled. */
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

#endif
