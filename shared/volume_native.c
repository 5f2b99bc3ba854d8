/* A cost volume's least costs per pixel in C with vectors: shared/volume_kernels.py's
 * least_costs, the same values and disparities bit for bit (costs are only compared and moved).
 *
 * Why C: numba's kernel inserts each cost behind a branch taken unpredictably (about 2.9 ns a
 * cost on Aloe's volume, 0.105 s); here the insertion is branch-free over the lanes of a vector
 * (eight pixels with AVX, four with SSE2 or NEON): each kept slot takes the slot before it, the
 * new cost, or itself, by the same strict comparisons (0.029 s with AVX2, 0.061 s with SSE2; a
 * test that skips vectors where no lane's cost goes in made it slower). Vectors are read and
 * written through pointers of 4-byte alignment, not memcpy: GCC's copies through the stack
 * stalled the 8-lane build (0.28 s).
 */
#include <stdint.h>

#if defined(__AVX__)
#define LANES 8 /* pixels in one vector */
#else
#define LANES 4
#endif
#define MAX_SLOTS 16 /* least costs kept per pixel */

typedef float vfloat __attribute__((vector_size(LANES * 4), aligned(4)));
typedef int32_t vint __attribute__((vector_size(LANES * 4), aligned(4)));

static inline vfloat fselect(vint mask, vfloat yes, vfloat no)
{
    return (vfloat)((mask & (vint)yes) | (~mask & (vint)no));
}

static inline vint iselect(vint mask, vint yes, vint no) { return (mask & yes) | (~mask & no); }

/* values (slots, rows, width) +inf beforehand and indices (slots, rows, width): each pixel's
 * `slots` least costs of volume (count, rows, width), ascending, disparity after disparity, a
 * cost going in before the first strictly greater kept one. 0, or 1 when slots is out of range
 * (numba's kernel then). */
int qhsm_least_costs(
    const float *volume, float *values, int32_t *indices, int64_t count, int64_t rows,
    int64_t width, int64_t slots)
{
    if (slots < 1 || slots > MAX_SLOTS)
        return 1;
    int64_t plane = rows * width;
    int64_t whole = width - width % LANES;
    for (int64_t y = 0; y < rows; y++) {
        float *kept = values + y * width;
        int32_t *held = indices + y * width;
        for (int64_t d = 0; d < count; d++) {
            const float *costs = volume + d * plane + y * width;
            vint disparity = (vint){0} + (int32_t)d;
            for (int64_t x = 0; x < whole; x += LANES) {
                vfloat value = *(const vfloat *)(costs + x);
                vfloat here = *(vfloat *)(kept + (slots - 1) * plane + x);
                vint below_here = value < here; /* no branch on it: taken unpredictably */
                vint here_index = *(vint *)(held + (slots - 1) * plane + x);
                for (int64_t s = slots - 1; s > 0; s--) {
                    vfloat above = *(vfloat *)(kept + (s - 1) * plane + x);
                    vint above_index = *(vint *)(held + (s - 1) * plane + x);
                    vint below_above = value < above;
                    vfloat moved = fselect(below_above, above, fselect(below_here, value, here));
                    vint moved_index = iselect(
                        below_above, above_index, iselect(below_here, disparity, here_index));
                    *(vfloat *)(kept + s * plane + x) = moved;
                    *(vint *)(held + s * plane + x) = moved_index;
                    here = above;
                    here_index = above_index;
                    below_here = below_above;
                }
                vfloat first = fselect(below_here, value, here);
                vint first_index = iselect(below_here, disparity, here_index);
                *(vfloat *)(kept + x) = first;
                *(vint *)(held + x) = first_index;
            }
            for (int64_t x = whole; x < width; x++) { /* the row's tail, one pixel at a time */
                float value = costs[x];
                if (!(value < kept[(slots - 1) * plane + x]))
                    continue;
                int64_t s = slots - 1;
                while (s > 0 && value < kept[(s - 1) * plane + x]) {
                    kept[s * plane + x] = kept[(s - 1) * plane + x];
                    held[s * plane + x] = held[(s - 1) * plane + x];
                    s--;
                }
                kept[s * plane + x] = value;
                held[s * plane + x] = (int32_t)d;
            }
        }
    }
    return 0;
}
