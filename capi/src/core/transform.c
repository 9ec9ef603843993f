/* Small host-side linear algebra for instance transforms. */
#include "core/core.h"

#include <math.h>

bool pn_affine_inverse(const float m[12], float inv[12])
{
    for (int i = 0; i < 12; ++i)
        if (!isfinite(m[i]))
            return false;
    /* Rows (a b c | tx), (d e f | ty), (g h i | tz); inverse of the 3x3 by cofactors, in double. */
    double a = m[0], b = m[1], c = m[2], d = m[4], e = m[5], f = m[6], g = m[8], h = m[9], i = m[10];
    double A = e * i - f * h, B = -(d * i - f * g), C = d * h - e * g;
    double det = a * A + b * B + c * C;
    double scale = fabs(a) + fabs(b) + fabs(c) + fabs(d) + fabs(e) + fabs(f) + fabs(g) + fabs(h) + fabs(i);
    /* Relative test: a matrix whose determinant vanishes against its size cubed is singular. */
    if (!(fabs(det) > 1e-12 * scale * scale * scale))
        return false;
    double r[9] = {A, -(b * i - c * h), b * f - c * e, B, a * i - c * g, -(a * f - c * d),
                   C, -(a * h - b * g), a * e - b * d};
    for (int k = 0; k < 9; ++k)
        r[k] /= det;
    double t[3] = {m[3], m[7], m[11]};
    for (int row = 0; row < 3; ++row) {
        inv[4 * row + 0] = (float)r[3 * row + 0];
        inv[4 * row + 1] = (float)r[3 * row + 1];
        inv[4 * row + 2] = (float)r[3 * row + 2];
        inv[4 * row + 3] = (float)-(r[3 * row] * t[0] + r[3 * row + 1] * t[1] + r[3 * row + 2] * t[2]);
    }
    return true;
}

float pn_uniform_scale(const float m[12])
{
    const float s = m[0];
    const float tol = 1e-5f * fabsf(s);
    if (!(s > 0.0f) || !isfinite(s))
        return 0.0f;
    for (int r = 0; r < 3; ++r) {
        if (!isfinite(m[4 * r + 3]))
            return 0.0f;
        for (int c = 0; c < 3; ++c)
            if (!(fabsf(m[4 * r + c] - (r == c ? s : 0.0f)) <= tol))
                return 0.0f;
    }
    return s;
}
