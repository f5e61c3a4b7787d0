/* The noise of the paired runs (sdm.sky_native): sdm.sky.add_target_noise's scatter into a NoiseBuffer.
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
#include "kernel.h"

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
