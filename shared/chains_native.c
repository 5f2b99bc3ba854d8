/* The chain kernel of dual decomposition and the chain primal step, in C with vectors:
 * shared/grid_kernels.py's _chains_windows, the same floats (compiled with -ffp-contract=off:
 * no fused multiply-adds), the chains in the lanes of three vectors at a time (twelve chains
 * with AVX's 4 doubles, six with SSE2's or NEON's 2).
 *
 * Why C: the kernel's messages run along a chain, each position's a dependent sequence of
 * additions and minima, so one chain leaves most of a core idle; numba keeps lanes of several
 * chains scalar (docs/benchmarks.md, "8 chains in lanes"). GCC's and Clang's vector extensions
 * put the lanes in SIMD registers. The read-back keeps labels and label differences as doubles
 * (small integers, exact): 64-bit integer lanes have no absolute value or conversion to
 * double before AVX-512 (nor a compare before SSE4.2), and cost the kernel 2x with AVX2.
 * shared/kernels.py calls it through ctypes when shared/kernel_build.py built it for this
 * source; the numba kernel stays the reference (tests/core/test_chains_native.py: equal bit for
 * bit).
 *
 * Every operation is _chains_windows' in the same order: min(a, b) is numba's (b if b < a
 * else a), the unary (min + scale * base) + sign * extra in float64, the read-back's first of
 * equal values, the penalty |d| * slope capped at truncation as _regulariser computes it.
 * Beside it the chain primal step's other kernel, the neighbour costs of a window grid
 * (_neighbour_costs_windows), likewise numba's floats.
 */
#include <stdint.h>
#include <stdlib.h>
#include <math.h>

/* vectors as wide as the target's registers: 4 doubles with AVX, else 2 (SSE2, NEON); wider
 * than the registers, the compiler lowers them through memory (4-5x slower than numba) */
#if defined(__AVX__)
#define LANES 4 /* chains in one vector */
#else
#define LANES 2
#endif
typedef double vdouble __attribute__((vector_size(LANES * 8), aligned(8)));
typedef int64_t vlong __attribute__((vector_size(LANES * 8), aligned(8)));

#define GROUPS 3                /* vectors in flight: independent work while one waits */
#define CHAINS (LANES * GROUPS) /* chains a step solves */
#define MAX_COUNT 64            /* candidates the envelope buffer holds */

/* numba's min(x, y): y where y < x, else x (NaN-free inputs: the same as a minimum) */
static inline vdouble vmin(vdouble x, vdouble y)
{
    vlong less = y < x;
    return (vdouble)((less & (vlong)y) | (~less & (vlong)x));
}

static inline vdouble vselect(vlong mask, vdouble yes, vdouble no)
{
    return (vdouble)((mask & (vlong)yes) | (~mask & (vlong)no));
}

static inline double smin(double x, double y) { return y < x ? y : x; }

/* One step's chains: messages[(x * count + k) * CHAINS + n] for chain a + n (the last chain
 * repeats itself in the lanes past the end; nothing of those lanes is written out). Inlined
 * into each call below, so that the preset's window widths (4 and 6) are constants there: its
 * candidate loops unrolled, 4-5 % faster. */
static inline __attribute__((always_inline)) void solve_step(
    const float *base, double scale, const float *extra, double sign, const int32_t *first,
    const double *weight, double slope, double truncation, int32_t *labels, int turned,
    int64_t chains, int64_t length, int64_t count, double *energies, int64_t a,
    double *messages, double *edges)
{
    /* the forward pass keeps each position's weights and window moves (first[x - 1] -
     * first[x], as doubles) in edges[x * 2 * CHAINS ...] for the read-back: gathering them
     * from the chains' rows again was a tenth of the kernel's time */
    double envelope_buffer[MAX_COUNT * CHAINS] __attribute__((aligned(32)));
    vdouble *envelope = (vdouble *)envelope_buffer;
    int64_t chain[CHAINS];
    const float *base_of[CHAINS], *extra_of[CHAINS];
    for (int n = 0; n < CHAINS; n++) {
        chain[n] = a + n < chains ? a + n : chains - 1;
        base_of[n] = base + chain[n] * length * count;
        extra_of[n] = extra + chain[n] * length * count;
    }
    for (int64_t k = 0; k < count; k++)
        for (int n = 0; n < CHAINS; n++)
            messages[k * CHAINS + n] =
                scale * (double)base_of[n][k] + sign * (double)extra_of[n][k];

    for (int64_t x = 1; x < length; x++) {
        double weights[CHAINS];
        int64_t shift[CHAINS];
        int same = 1;
        for (int n = 0; n < CHAINS; n++) {
            weights[n] = weight[chain[n] * (length - 1) + x - 1];
            shift[n] = first[chain[n] * length + x] - first[chain[n] * length + x - 1];
            same &= shift[n] == 0;
        }
        vdouble w[GROUPS], step[GROUPS], lowest[GROUPS], running[GROUPS], ceiling[GROUPS];
        const vdouble *previous = (const vdouble *)(messages + (x - 1) * count * CHAINS);
        vdouble *current = (vdouble *)(messages + x * count * CHAINS);
        /* the lower envelope of the cones s w |j - t| over the previous messages */
        vdouble *kept = (vdouble *)(edges + x * 2 * CHAINS);
        for (int g = 0; g < GROUPS; g++) {
            w[g] = *(const vdouble *)(weights + g * LANES);
            kept[g] = w[g];
            vlong moves = -*(const vlong *)(shift + g * LANES); /* first[x - 1] - first[x] */
            kept[GROUPS + g] = __builtin_convertvector(moves, vdouble);
            step[g] = w[g] * slope;
            lowest[g] = previous[g];
            running[g] = lowest[g];
            envelope[g] = running[g];
        }
        for (int64_t j = 1; j < count; j++)
            for (int g = 0; g < GROUPS; g++) {
                vdouble value = previous[j * GROUPS + g];
                lowest[g] = vmin(lowest[g], value);
                running[g] = vmin(value, running[g] + step[g]);
                envelope[j * GROUPS + g] = running[g];
            }
        for (int64_t j = count - 2; j >= 0; j--)
            for (int g = 0; g < GROUPS; g++) {
                running[g] = vmin(envelope[j * GROUPS + g], running[g] + step[g]);
                envelope[j * GROUPS + g] = running[g];
            }
        for (int g = 0; g < GROUPS; g++)
            ceiling[g] = lowest[g] + w[g] * truncation;
        if (same) { /* every chain keeps its window (most positions) */
            for (int64_t k = 0; k < count; k++)
                for (int g = 0; g < GROUPS; g++) {
                    double unaries[LANES], addeds[LANES];
                    for (int i = 0; i < LANES; i++) {
                        unaries[i] = (double)base_of[g * LANES + i][x * count + k];
                        addeds[i] = (double)extra_of[g * LANES + i][x * count + k];
                    }
                    vdouble unary = *(const vdouble *)unaries, added = *(const vdouble *)addeds;
                    current[k * GROUPS + g] =
                        (vmin(envelope[k * GROUPS + g], ceiling[g]) + scale * unary) +
                        sign * added;
                }
            continue;
        }
        /* a window moved: each chain's message at t = k + shift, below, inside or beyond */
        for (int n = 0; n < CHAINS; n++) {
            int64_t moved = shift[n];
            int64_t low = -moved > 0 ? -moved : 0;
            if (low > count)
                low = count;
            int64_t high = count - moved < count ? count - moved : count;
            if (high < low)
                high = low;
            double slope_here = step[n / LANES][n % LANES];
            double cap = ceiling[n / LANES][n % LANES];
            const float *unary = base_of[n] + x * count, *added = extra_of[n] + x * count;
            for (int64_t k = 0; k < count; k++) {
                double value;
                if (k < low)
                    value = envelope_buffer[n] - slope_here * (double)(k + moved);
                else if (k < high)
                    value = envelope_buffer[(k + moved) * CHAINS + n];
                else
                    value = envelope_buffer[(count - 1) * CHAINS + n] +
                            slope_here * (double)(k + moved - count + 1);
                messages[(x * count + k) * CHAINS + n] =
                    (smin(value, cap) + scale * (double)unary[k]) + sign * (double)added[k];
            }
        }
    }

    /* the read-back: the best last label, then each position's predecessor that gave the
     * message its value (the first of equal values); labels and label differences as doubles
     * (small integers, exact), so that every step stays in the double lanes */
    vdouble arg[GROUPS], best[GROUPS];
    const vdouble *last = (const vdouble *)(messages + (length - 1) * count * CHAINS);
    for (int g = 0; g < GROUPS; g++) {
        arg[g] = (vdouble){0};
        best[g] = last[g];
    }
    for (int64_t k = 1; k < count; k++)
        for (int g = 0; g < GROUPS; g++) {
            vlong better = last[k * GROUPS + g] < best[g];
            best[g] = vselect(better, last[k * GROUPS + g], best[g]);
            arg[g] = vselect(better, (vdouble){0} + (double)k, arg[g]);
        }
    for (int n = 0; n < CHAINS && a + n < chains; n++) {
        int32_t label = (int32_t)arg[n / LANES][n % LANES];
        energies[a + n] = best[n / LANES][n % LANES];
        if (turned)
            labels[(length - 1) * chains + a + n] = label;
        else
            labels[(a + n) * length + length - 1] = label;
    }
    const vdouble infinite = (vdouble){0} + INFINITY;
    const vdouble cap = (vdouble){0} + truncation;
    const vlong magnitude = (vlong){0} + INT64_MAX; /* all bits but the sign: |d| */
    for (int64_t x = length - 1; x > 0; x--) {
        const vdouble *kept = (const vdouble *)(edges + x * 2 * CHAINS);
        vdouble w[GROUPS], smallest[GROUPS];
        vdouble difference[GROUPS]; /* label difference at j = 0: first[x-1] - (first[x] + arg) */
        for (int g = 0; g < GROUPS; g++) {
            w[g] = kept[g];
            difference[g] = kept[GROUPS + g] - arg[g];
            smallest[g] = infinite;
        }
        const vdouble *previous = (const vdouble *)(messages + (x - 1) * count * CHAINS);
        for (int64_t j = 0; j < count; j++)
            for (int g = 0; g < GROUPS; g++) {
                vdouble distance = (vdouble)((vlong)(difference[g] + (double)j) & magnitude);
                vdouble penalty = distance * slope;
                penalty = vmin(penalty, cap); /* cap where penalty > cap: one minimum */
                vdouble value = previous[j * GROUPS + g] + w[g] * penalty;
                vlong better = value < smallest[g];
                smallest[g] = vselect(better, value, smallest[g]);
                arg[g] = vselect(better, (vdouble){0} + (double)j, arg[g]);
            }
        for (int n = 0; n < CHAINS && a + n < chains; n++) {
            int32_t label = (int32_t)arg[n / LANES][n % LANES];
            if (turned)
                labels[(x - 1) * chains + a + n] = label;
            else
                labels[(a + n) * length + x - 1] = label;
        }
    }
}

/* _chains_windows over C-contiguous arrays: base and extra (chains, length, count) float32,
 * first (chains, length) int32, weight (chains, length - 1) float64, labels (chains, length)
 * int32, or (length, chains) when turned; each chain's optimum into energies (chains).
 * Returns 0, or 1 for a window wider than MAX_COUNT or empty chains (left to numba), 2 when
 * out of memory (nothing solved). */
int qhsm_chains_windows(
    const float *base, double scale, const float *extra, double sign, const int32_t *first,
    const double *weight, double slope, double truncation, int32_t *labels, int turned,
    int64_t chains, int64_t length, int64_t count, double *energies)
{
    if (count > MAX_COUNT || count < 1 || length < 1)
        return 1;
    if (chains < 1)
        return 0;
    double *messages = malloc(sizeof(double) * (size_t)(length * (count + 2) * CHAINS));
    if (messages == NULL)
        return 2;
    double *edges = messages + length * count * CHAINS;
    for (int64_t a = 0; a < chains; a += CHAINS) {
        if (count == 6) /* the accurate preset's windows */
            solve_step(base, scale, extra, sign, first, weight, slope, truncation, labels, turned,
                       chains, length, 6, energies, a, messages, edges);
        else if (count == 4) /* and its finest level's */
            solve_step(base, scale, extra, sign, first, weight, slope, truncation, labels, turned,
                       chains, length, 4, energies, a, messages, edges);
        else
            solve_step(base, scale, extra, sign, first, weight, slope, truncation, labels, turned,
                       chains, length, count, energies, a, messages, edges);
    }
    free(messages);
    return 0;
}

/* shared/grid_kernels.py's _regulariser of a label difference: |d| * slope, capped */
static inline double regulariser(int64_t difference, double slope, double truncation)
{
    double penalty = (double)(difference < 0 ? -difference : difference) * slope;
    return penalty > truncation ? truncation : penalty;
}

/* one pixel's costs o[k] = w_before * before[k] + w_after * after[k] (rounded to float) */
static inline __attribute__((always_inline)) void neighbour_pixel(
    float *o, const double *before, const double *after, double weight_before,
    double weight_after, int64_t count)
{
    for (int64_t k = 0; k < count; k++) {
        double ahead = weight_after * after[k];
        o[k] = (float)(weight_before * before[k] + ahead);
    }
}

/* _neighbour_costs_windows over C-contiguous arrays: first and labels (height, width) int32,
 * weight_h (height, width - 1) and weight_v (height - 1, width) float64, out (height, width,
 * count) float32: each candidate's edge costs to its fixed neighbours above and below
 * (vertical) or left and right, the regulariser from the same table of label differences
 * (_label_table). Returns 0, or 2 when out of memory (nothing written). numba's kernel leaves
 * its candidate loop's count unknown; here the preset's 4 and 6 are constants (2x faster). */
int qhsm_neighbour_costs_windows(
    const int32_t *first, const double *weight_h, const double *weight_v, double slope,
    double truncation, const int32_t *labels, int vertical, int64_t height, int64_t width,
    int64_t count, float *out)
{
    if (height < 1 || width < 1)
        return 0;
    int32_t lowest = first[0], highest = first[0];
    for (int64_t i = 1; i < height * width; i++) {
        lowest = first[i] < lowest ? first[i] : lowest;
        highest = first[i] > highest ? first[i] : highest;
    }
    int64_t reach = (int64_t)highest - lowest + count;
    double *table = malloc(sizeof(double) * (size_t)(2 * reach + 1));
    if (table == NULL)
        return 2;
    for (int64_t d = -reach; d <= reach; d++)
        table[d + reach] = regulariser(d, slope, truncation);
    for (int64_t y = 0; y < height; y++)
        for (int64_t x = 0; x < width; x++) {
            int64_t p = y * width + x, here = first[p], before = here, after = here;
            double weight_before = 0.0, weight_after = 0.0; /* no neighbour: weight 0 */
            if (vertical) {
                if (y > 0) {
                    before = (int64_t)first[p - width] + labels[p - width];
                    weight_before = weight_v[p - width];
                }
                if (y + 1 < height) {
                    after = (int64_t)first[p + width] + labels[p + width];
                    weight_after = weight_v[p];
                }
            } else {
                if (x > 0) {
                    before = (int64_t)first[p - 1] + labels[p - 1];
                    weight_before = weight_h[y * (width - 1) + x - 1];
                }
                if (x + 1 < width) {
                    after = (int64_t)first[p + 1] + labels[p + 1];
                    weight_after = weight_h[y * (width - 1) + x];
                }
            }
            const double *from_before = table + (here - before + reach);
            const double *from_after = table + (here - after + reach);
            float *o = out + p * count;
            if (count == 6)
                neighbour_pixel(o, from_before, from_after, weight_before, weight_after, 6);
            else if (count == 4)
                neighbour_pixel(o, from_before, from_after, weight_before, weight_after, 4);
            else
                neighbour_pixel(o, from_before, from_after, weight_before, weight_after, count);
        }
    free(table);
    return 0;
}
