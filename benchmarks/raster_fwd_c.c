/* Forward compositing kernel in C with OpenMP: the same algorithm as
 * gs2e.splat.raster.raster_forward_kernel (double locals, float storage).
 * Used only by benchmarks/bench_rasterizer.py to compare numba with a
 * compiled extension; built there with `gcc -O3 -fopenmp -shared -fPIC`. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

void raster_fwd(const int64_t *offsets, const int32_t *gids, const float *means2d,
                const float *conics, const float *opac, const float *feats, int C,
                const float *bg, int width, int height, int tile, float *out,
                float *out_T, int32_t *n_contrib) {
    int tiles_x = (width + tile - 1) / tile, tiles_y = (height + tile - 1) / tile;
    int n_tiles = tiles_x * tiles_y;
#pragma omp parallel for schedule(dynamic, 1)
    for (int t = 0; t < n_tiles; t++) {
        int ty = t / tiles_x, tx = t % tiles_x;
        int64_t start = offsets[t], m = offsets[t + 1] - start;
        double *l = malloc(sizeof(double) * (m * (6 + C) + 1));
        double *lu = l, *lv = l + m, *la = l + 2 * m, *lb = l + 3 * m, *lc = l + 4 * m,
               *lo = l + 5 * m, *lf = l + 6 * m;
        for (int64_t k = 0; k < m; k++) {
            int g = gids[start + k];
            lu[k] = means2d[2 * g]; lv[k] = means2d[2 * g + 1];
            la[k] = conics[3 * g]; lb[k] = conics[3 * g + 1]; lc[k] = conics[3 * g + 2];
            lo[k] = opac[g];
            for (int c = 0; c < C; c++) lf[k * C + c] = feats[g * C + c];
        }
        double *rx = malloc(sizeof(double) * (m + 1)), *ry = malloc(sizeof(double) * (m + 1));
        int64_t *rl = malloc(sizeof(int64_t) * (m + 1)), *sl = malloc(sizeof(int64_t) * (m + 1));
        double *lpm = malloc(sizeof(double) * (m + 1));
        for (int64_t k = 0; k < m; k++) {
            double det = la[k] * lc[k] - lb[k] * lb[k];
            if (lo[k] < 1.0 / 255.0 || !(det > 0.0)) { lpm[k] = 1.0; rx[k] = -1.0; ry[k] = -1.0; continue; }
            double t = log((1.0 / 255.0) / lo[k]);
            lpm[k] = (t > -4.5 ? t : -4.5) - 1e-6;
            double m2 = -2.0 * lpm[k];
            rx[k] = sqrt(m2 * lc[k] / det) * (1.0 + 1e-6) + 1e-3;
            ry[k] = sqrt(m2 * la[k] / det) * (1.0 + 1e-6) + 1e-3;
        }
        double acc[16];
        int64_t mr = 0, ms = 0;
        int i1 = (ty + 1) * tile < height ? (ty + 1) * tile : height;
        int j1 = (tx + 1) * tile < width ? (tx + 1) * tile : width;
        for (int i = ty * tile; i < i1; i++) {
            double py = i + 0.5;
            mr = 0;
            for (int64_t k = 0; k < m; k++) { rl[mr] = k; mr += fabs(lv[k] - py) <= ry[k]; }
            for (int j = tx * tile; j < j1; j++) {
                if ((j - tx * tile) % 4 == 0) {
                    double x0 = j + 0.5, x1 = (j + 4 < j1 ? j + 4 : j1) - 0.5;
                    ms = 0;
                    for (int64_t r = 0; r < mr; r++) {
                        int64_t k = rl[r];
                        sl[ms] = k;
                        ms += (lu[k] + rx[k] >= x0) && (lu[k] - rx[k] <= x1);
                    }
                }
                double px = j + 0.5, T = 1.0;
                for (int c = 0; c < C; c++) acc[c] = 0.0;
                int64_t last = m;
                for (int64_t r = 0; r < ms; r++) {
                    int64_t k = sl[r];
                    double dx = lu[k] - px, dy = lv[k] - py;
                    double power = -0.5 * (la[k] * dx * dx + lc[k] * dy * dy) - lb[k] * dx * dy;
                    if (power > 0.0 || power < lpm[k]) continue;
                    if (power < -4.5) continue;
                    double alpha = lo[k] * exp(power);
                    if (alpha > 0.99) alpha = 0.99;
                    if (alpha < 1.0 / 255.0) continue;
                    double tn = T * (1.0 - alpha);
                    if (tn < 1e-4) { last = k; break; }
                    double w = alpha * T;
                    for (int c = 0; c < C; c++) acc[c] += lf[k * C + c] * w;
                    T = tn;
                }
                for (int c = 0; c < C; c++) out[((int64_t)i * width + j) * C + c] = (float)(acc[c] + T * bg[c]);
                out_T[(int64_t)i * width + j] = (float)T;
                n_contrib[(int64_t)i * width + j] = (int32_t)last;
            }
        }
        free(l); free(lpm); free(rx); free(ry); free(rl); free(sl);
    }
}
