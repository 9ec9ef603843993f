/* The sample grid of an occlusion field (docs/fiv.md).
 *
 * A sample is indexed (k, i, j): radius k of n_rho, polar angle i of n_theta
 * (theta_i = pi i / (n_theta - 1), both poles included), azimuth j of n_phi
 * (phi_j = 2 pi j / n_phi, periodic). d(theta, phi) is the direction from the
 * receiver to the occluder's bounding-sphere centre c, so the receiver sits
 * at c - rho_k d. Radii grow geometrically from rho_min to rho_max:
 * rho_k = rho_min (rho_max / rho_min)^(k / (n_rho - 1)). */
#ifndef PN_COMMON_FIV_GRID_CL
#define PN_COMMON_FIV_GRID_CL

#include "common/math.cl"

inline float3 pn_fiv_direction(float theta, float phi)
{
    float st = sin(theta);
    return (float3)(st * cos(phi), cos(theta), st * sin(phi));
}

/* Samples of one sample: X rgb, Y rgb, Z rgb (FIV = X d.x + Y d.y + Z d.z per channel). */
#define PN_FIV_FLOATS 9

#endif
