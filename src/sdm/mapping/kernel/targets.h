/* The runs' targets as the trainer reads them: the zoomed-out levels of a run's pyramid and a level-0 target's
 * active pixels (group_crossing's mismatch), inlined into the trainer's loops; closed_centred_r1's closing
 * (targets.c).
 */
#ifndef SDM_TARGETS_H
#define SDM_TARGETS_H

#include "kernel.h"

/* One level up a pyramid of 0/1 targets: n targets of h x w (h, w even) to h/2 x w/2, each block the OR of its
 * 2 x 2 (sdm.zoom.target_pyramid; exact in any order). The n targets' rows are one array of n * h rows, so
 * output row t is the OR of input rows 2t and 2t + 1. */
static inline void halve_targets(int64_t n, int64_t h, int64_t w, const uint8_t *restrict finer,
                                 uint8_t *restrict coarser) {
    for (int64_t t = 0; t < n * (h / 2); ++t) {
        const uint8_t *top = finer + 2 * t * w, *bottom = top + w;
        uint8_t *out = coarser + t * (w / 2);
        for (int64_t c = 0; c < w / 2; ++c)
            out[c] = (uint8_t)((top[2 * c] | top[2 * c + 1]) | (bottom[2 * c] | bottom[2 * c + 1]));
    }
}

/* Whether any of n_runs runs (targets: their rows of n_levels addresses) leaves a level above 0 to the kernel to
 * zoom out (its pyramid then fills `pyramid`). */
static inline int zooms_any(int64_t n_runs, int64_t n_levels, const int64_t *targets, const int64_t *levels) {
    for (int64_t run = 0; run < n_runs; ++run)
        for (int64_t li = 0; li < n_levels; ++li)
            if (targets[run * n_levels + li] == 0 && levels[li] > 0) return 1;
    return 0;
}

/* The active pixels of a 0/1 byte grid of n cells: eight bytes to a word, summed in 16-bit lanes (each lane
 * holds at most 2 * 255 after 255 words), so the loop streams the grid instead of widening every byte to
 * 64 bits; the rest byte by byte. */
static inline int64_t count_active(int64_t n, const uint8_t *grid) {
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

/* closed_centred_r1's target closed (targets.c). */
KERNEL_INTERNAL void close3(int64_t h, int64_t w, const uint8_t *restrict src, uint8_t *restrict dst,
                            uint8_t *restrict tmp);

#endif
