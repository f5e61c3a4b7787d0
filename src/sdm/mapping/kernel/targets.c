/* closed_centred_r1's target in the trainer (sdm_train's mode 1): each configuration's closed the first time a
 * run needs it. */
#include "targets.h"

/* closed_centred_r1's target: the 3x3 closing of one configuration's h x w 0/1 target (sdm.mapping.rules.closing(3),
 * _spread's OR then AND of the neighbours along rows, then columns; neighbours beyond the grid left out), from
 * src into dst through tmp (h * w bytes each). */
void close3(int64_t h, int64_t w, const uint8_t *restrict src, uint8_t *restrict dst, uint8_t *restrict tmp) {
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
