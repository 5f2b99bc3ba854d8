/* The colour-weighted median of OpenCV's ximgproc (cv::ximgproc::weightedMedianFilter, WMF_EXP,
 * 8-bit values, no mask: Zhang, Xu and Jia, "100+ Times Faster Weighted Median Filter", CVPR
 * 2014), the same medians bit for bit, on a range of image columns: shared/filters.py runs the
 * ranges on the budget's cores at once.
 *
 * Why C: OpenCV's filter takes one core and cannot share a process with itself (a static colour
 * hash in its feature indexing, static temporaries in its histogram bookkeeping), yet each image
 * column is filtered on its own: its joint histogram and cut point start afresh at every column.
 * These functions keep no state outside their arguments. The guide's colour clusters still come
 * from OpenCV's k-means (shared/filters.py, seeded as OpenCV's filter seeds it), so only the
 * weights between clusters and the column scan are here.
 *
 * Every float operation is OpenCV's in the same order (compiled with -ffp-contract=off: no fused
 * multiply-adds): the weights in float with expf, each balance summed along the same linked
 * lists, the same cut-point walk; tests/core/test_median_native.py checks against OpenCV.
 */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <math.h>

#define VALUES 256 /* 8-bit values: the histogram's rows */

/* weights[i * features + j]: WMF_EXP's weight between feature indices i and j. channels 1:
 * indices are the gray levels (features 256); channels 3: centers[i * 3 + c] are the k-means
 * centres of the 6-bit colours (OpenCV's featureIndexing). */
void qhsm_median_weights(
    const float *centers, int64_t features, int64_t channels, float sigma, float *weights)
{
    float scaled = channels == 3 ? sigma / 256.0f * 64 : sigma;
    float divider = (1.0f / (2 * scaled * scaled));
    for (int64_t i = 0; i < features; i++)
        for (int64_t j = i; j < features; j++) {
            float distance;
            if (channels == 3) {
                const float *a = centers + i * 3, *b = centers + j * 3;
                float d0 = a[0] - b[0], d1 = a[1] - b[1], d2 = a[2] - b[2];
                distance = d0 * d0 + d1 * d1 + d2 * d2;
            } else {
                float d = fabsf((float)(i - j));
                distance = d * d;
            }
            float value = expf(-(distance)*divider);
            weights[i * features + j] = weights[j * features + i] = value;
        }
}

/* A count in a linked list of the non-zero counts (OpenCV's "necklace" of the balance counts):
 * link i after the head when its count leaves 0, unlink it when it returns to 0. */
static inline void update_balance(int32_t *count, int32_t *next, int32_t *previous, int32_t i,
                                  int32_t change)
{
    if (i) {
        if (!*count) {
            int32_t after = next[0];
            next[0] = i;
            next[i] = after;
            previous[after] = i;
            previous[i] = 0;
        } else if (!(*count + change)) {
            int32_t before = previous[i], after = next[i];
            next[before] = after;
            previous[after] = before;
        }
    }
    *count += change;
}

/* Pixel (value, feature) enters the joint histogram: link feature in value's list when its count
 * leaves 0 (feature 0 is the head and never linked). */
static inline void enter(int32_t *histogram, int32_t *next, int32_t *previous, int32_t feature)
{
    if (!histogram[feature] && feature) {
        int32_t after = next[0];
        next[feature] = after;
        previous[feature] = 0;
        next[0] = previous[after] = feature;
    }
    histogram[feature]++;
}

static inline void leave(int32_t *histogram, int32_t *next, int32_t *previous, int32_t feature)
{
    histogram[feature]--;
    if (!histogram[feature] && feature) {
        int32_t before = previous[feature], after = next[feature];
        next[before] = after;
        previous[after] = before;
    }
}

/* A column's scan state: the joint histogram (value x feature counts, each value's linked list
 * of the features it holds) and the balance counts (per feature: pixels below the cut minus
 * those above, with their linked list). */
typedef struct {
    int32_t *histogram, *next, *previous;
    int32_t *balance, *balance_next, *balance_previous;
    int64_t features;
} Scan;

/* The pixels of image row `row` in columns left..right enter the window (entering) or leave
 * it: counted in, or out of, the histogram and the balance (+1 below the cut, -1 above). */
static void move_row(Scan *scan, const uint8_t *values, const uint8_t *features_of, int64_t cols,
                     int64_t row, int64_t left, int64_t right, int32_t median, int entering)
{
    for (int64_t j = left; j <= right; j++) {
        int32_t value = values[row * cols + j], feature = features_of[row * cols + j];
        int64_t at = value * scan->features;
        int32_t side = ((value <= median) << 1) - 1;
        if (entering) {
            enter(scan->histogram + at, scan->next + at, scan->previous + at, feature);
        } else {
            leave(scan->histogram + at, scan->next + at, scan->previous + at, feature);
            side = -side;
        }
        update_balance(&scan->balance[feature], scan->balance_next, scan->balance_previous,
                       feature, side);
    }
}

/* Columns first..last-1 of out (rows x cols, 8 bits): each pixel's median of values in its
 * (2 radius + 1)^2 window, weighted by weights[feature of the pixel][feature of each]. 0, or 2
 * without memory. */
int qhsm_weighted_median(
    const uint8_t *values, const uint8_t *features_of, const float *weights, int64_t rows,
    int64_t cols, int64_t radius, int64_t features, int64_t first, int64_t last, uint8_t *out)
{
    size_t cells = (size_t)VALUES * (size_t)features;
    int32_t *histogram = malloc(sizeof(int32_t) * cells);
    int32_t *next = malloc(sizeof(int32_t) * cells);
    int32_t *previous = malloc(sizeof(int32_t) * cells);
    int32_t *balance = malloc(sizeof(int32_t) * (size_t)features);
    int32_t *balance_next = malloc(sizeof(int32_t) * (size_t)features);
    int32_t *balance_previous = malloc(sizeof(int32_t) * (size_t)features);
    int status = 0;
    if (!histogram || !next || !previous || !balance || !balance_next || !balance_previous) {
        status = 2;
        goto done;
    }
    Scan scan = {histogram, next, previous, balance, balance_next, balance_previous, features};
    for (int64_t x = first; x < last; x++) {
        memset(balance, 0, sizeof(int32_t) * (size_t)features);
        memset(histogram, 0, sizeof(int32_t) * cells);
        for (int64_t v = 0; v < VALUES; v++)
            next[v * features] = previous[v * features] = 0;
        balance_next[0] = balance_previous[0] = 0;
        int32_t median = -1; /* the cut: values <= median are below it */
        int64_t left = x - radius < 0 ? 0 : x - radius;
        int64_t right = x + radius > cols - 1 ? cols - 1 : x + radius;
        int64_t top = rows - 1 < radius ? rows - 1 : radius;
        for (int64_t y = 0; y <= top; y++) /* every pixel above the cut at -1 */
            move_row(&scan, values, features_of, cols, y, left, right, median, 1);
        for (int64_t y = 0; y < rows; y++) {
            float total = 0;
            const float *weight = weights + (int64_t)features_of[y * cols + x] * features;
            int32_t i = 0;
            do {
                total += balance[i] * weight[i];
                i = balance_next[i];
            } while (i);
            if (total >= 0) { /* the cut moves down */
                for (; total >= 0 && median > 0; median--) {
                    float moved = 0;
                    int64_t row = (int64_t)median * features;
                    const int32_t *counts = histogram + row;
                    i = 0;
                    do {
                        moved += (counts[i] << 1) * weight[i];
                        update_balance(&balance[i], balance_next, balance_previous, i,
                                       -(counts[i] << 1));
                        i = next[row + i];
                    } while (i);
                    total -= moved;
                }
            } else { /* up */
                for (; total < 0 && median != VALUES - 1; median++) {
                    float moved = 0;
                    int64_t row = (int64_t)(median + 1) * features;
                    const int32_t *counts = histogram + row;
                    i = 0;
                    do {
                        moved += (counts[i] << 1) * weight[i];
                        update_balance(&balance[i], balance_next, balance_previous, i,
                                       counts[i] << 1);
                        i = next[row + i];
                    } while (i);
                    total += moved;
                }
            }
            if (median != -1)
                out[y * cols + x] = (uint8_t)(total < 0 ? median + 1 : median);
            else
                out[y * cols + x] = values[y * cols + x];
            if (y + radius + 1 < rows)
                move_row(&scan, values, features_of, cols, y + radius + 1, left, right, median, 1);
            if (y - radius >= 0)
                move_row(&scan, values, features_of, cols, y - radius, left, right, median, 0);
        }
    }
done:
    free(histogram);
    free(next);
    free(previous);
    free(balance);
    free(balance_next);
    free(balance_previous);
    return status;
}
