/* The CMA-ES baseline's count (sdm.experiments.baselines.cmaes_native): the exact zoom-0 pixel mismatch for many thetas
 * (sdm.experiments.baselines.mismatch).
 *
 * sdm_pixel_mismatch <-> sdm.experiments.baselines.mismatch.ShiftLayout.rendered_ids + PixelMismatch's count: the same
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
 * memo:         the last counts of this table, L = n_slots >= K slots (sdm.experiments.baselines.mismatch.MismatchMemo):
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
#include "kernel.h"

/* Whether the groups lo..hi-1 shift alike in two candidates' shifts. */
static inline int same_shifts(const int64_t *restrict one, const int64_t *restrict other, int64_t lo, int64_t hi) {
    for (int64_t g = lo; g < hi; ++g)
        if (one[g] != other[g]) return 0;
    return 1;
}

/* Candidate (a, b)'s whole shift of every group into offset (G,), as a padded-pixel offset, while each can be
 * trusted (ShiftLayout.rendered_ids's bounds); whether all of them can. */
static inline int group_shifts(double a, double b, int64_t n_groups, const double *gain, const double *frac_bounds,
                               const double *shift_low, const double *shift_high, int64_t padded_width,
                               int64_t *offset) {
    const double *frac_high = frac_bounds + 2 * n_groups;
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
    return trusted;
}

/* A slot whose candidate shifts groups g_lo..g_hi-1 as candidate k of this call (its shifts: `offset`) does, or
 * -1: this call's earlier candidates first, then the earlier calls' valid slots. */
static inline int64_t known_slot(int64_t k, const int64_t *offset, int64_t g_lo, int64_t g_hi, int64_t n_groups,
                                 int64_t n_slots, int64_t next, const int64_t *slot_offsets, const int64_t *counts,
                                 const int64_t *valid) {
    for (int64_t j = 0; j < k; ++j)
        if (counts[j] >= 0 && same_shifts(offset, slot_offsets + ((next + j) % n_slots) * n_groups, g_lo, g_hi))
            return (next + j) % n_slots;
    for (int64_t other = 0; other < n_slots; ++other)
        if (valid[other] && same_shifts(offset, slot_offsets + other * n_groups, g_lo, g_hi)) return other;
    return -1;
}

/* One configuration's sum (FP - TP) for a candidate whose groups g_lo..g_hi-1 shift by `offset`, its padded pixels
 * stamped with `mark` (weights: the configuration's table). */
static inline int64_t configuration_sum(int64_t g_lo, int64_t g_hi, const int64_t *offset, const int64_t *group_start,
                                        const int32_t *cells, const int8_t *weights, uint32_t *stamp, uint32_t mark) {
    int64_t sum = 0;
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
    return sum;
}

void sdm_pixel_mismatch(int64_t n_candidates, const double *theta, int64_t n_groups, int64_t n_configs,
                        const double *gain, const double *frac_bounds, const double *shift_low,
                        const double *shift_high, const int64_t *group_start, const int64_t *config_group,
                        const int32_t *cells, const int8_t *table, int64_t cells_per_config, int64_t padded_width,
                        const double *limits, int64_t n_target, int64_t n_slots, int64_t *slot_offsets,
                        int64_t *slot_sums, int64_t *state, uint32_t *stamp, int64_t *counts) {
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
        if (group_shifts(a, b, n_groups, gain, frac_bounds, shift_low, shift_high, padded_width, offset))
            counts[k] = n_target; /* plus FP - TP so far: never below 0 while it adds up */
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
        const int64_t g_lo = config_group[c], g_hi = config_group[c + 1];
        for (int64_t k = 0; k < n_candidates; ++k) {
            if (counts[k] < 0) continue;
            const int64_t slot = (next + k) % n_slots;
            const int64_t *offset = slot_offsets + slot * n_groups;
            const int64_t known = known_slot(k, offset, g_lo, g_hi, n_groups, n_slots, next, slot_offsets, counts,
                                             valid);
            const int64_t sum = known >= 0 ? slot_sums[known * n_configs + c]
                                           : configuration_sum(g_lo, g_hi, offset, group_start, cells,
                                                               table + c * cells_per_config, stamp, ++last);
            slot_sums[slot * n_configs + c] = sum;
            counts[k] += sum;
        }
    }
    stamp[cells_per_config] = last;
    for (int64_t k = 0; k < n_candidates; ++k) valid[(next + k) % n_slots] = counts[k] >= 0;
    state[n_slots] = (next + n_candidates) % n_slots;
}
