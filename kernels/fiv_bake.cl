/* Occlusion-field bake (docs/fiv.md): for every sample of one sphere of the
 * grid, the Fullsphere Irradiance Vector of the env radiance the occluder
 * hides from that point,
 *   FIV = sum over directions w hit by the occluder of L(w) w dw,
 * over the host's direction records (cube texels with exact solid angles,
 * bright texels split). Only directions inside the bounding cone of the
 * occluder's bounding sphere are traced: the others cannot hit it. The
 * occluder is the only instance of the scene, at identity. Samples found
 * inside the geometry (fiv_inside_sphere, run first) trace nothing. */
#include "common/fiv_grid.cl"
#include "common/raytrace.cl"

kernel void fiv_bake_sphere(PN_SCENE_ARGS, global const float4 *records, int record_count, float4 sphere,
                            int n_theta, int n_phi, float rho, global const uchar *inside, global float *out,
                            global uint *rays)
{
    int gid = get_global_id(0);
    if (gid >= n_theta * n_phi)
        return;
    int i = gid / n_phi, j = gid % n_phi;
    /* All azimuths of a pole are one point: the host copies sample j = 0. */
    if ((i == 0 || i == n_theta - 1) && j > 0)
        return;
    if (inside[gid]) { /* never used: no rays */
        rays[gid] = 0;
        return;
    }
    pn_scene_view scene = pn_make_scene_view(tlas, instances, blas, tris, instance_count);
    float3 d = pn_fiv_direction(PN_PI * (float)i / (float)(n_theta - 1), PN_TWO_PI * (float)j / (float)n_phi);
    float3 p = sphere.xyz - rho * d;
    /* Cosine of the bounding cone's half-angle, widened by 1e-4 R so that
     * rounding never drops a direction that grazes the sphere. */
    float s = sphere.w * 1.0001f / rho;
    float cos_cone = s < 1.0f ? sqrt(1.0f - s * s) : -2.0f;
    float3 x = (float3)(0.0f), y = (float3)(0.0f), z = (float3)(0.0f);
    uint traced = 0;
    for (int k = 0; k < record_count; ++k) {
        float4 rec = records[2 * k];
        if (dot(rec.xyz, d) < cos_cone)
            continue;
        ++traced;
        pn_hit hit;
        if (!pn_trace(scene, p, rec.xyz, 0.0f, INFINITY, &hit, true))
            continue;
        float3 l = records[2 * k + 1].xyz * rec.w;
        x += l * rec.x;
        y += l * rec.y;
        z += l * rec.z;
    }
    global float *o = out + PN_FIV_FLOATS * gid;
    vstore3(x, 0, o);
    vstore3(y, 1, o);
    vstore3(z, 2, o);
    rays[gid] = traced;
}

/* Solid angle of triangle (a, b, c) seen from the origin, signed by its
 * orientation (Van Oosterom and Strackee 1983). */
inline float pn_triangle_solid_angle(float3 a, float3 b, float3 c)
{
    float la = length(a), lb = length(b), lc = length(c);
    float num = dot(a, cross(b, c));
    float den = la * lb * lc + dot(a, b) * lc + dot(a, c) * lb + dot(b, c) * la;
    return 2.0f * atan2(num, den);
}

/* Far nodes count as dipoles beyond this many times their radius. Barill et
 * al. 2018 use 2 with second-order terms; with the dipole alone, 2 misjudged
 * samples up to 0.02 from the 1/2 threshold (a torus with holes), 4 none of
 * them, and the inside tests of a 65x128x30 bunny bake still take under a
 * second on two CPU cores. */
#define PN_WINDING_BETA 4.0f

/* Generalised winding number of the occluder around every sample of one
 * sphere (Jacobson et al. 2013): above 1/2 the sample is inside the
 * geometry. Only spheres inside the bounding sphere are tested. Evaluated
 * over the mesh's BVH (host-built node moments, capi/src/fiv_bake.c): a node
 * seen from beyond PN_WINDING_BETA times its radius adds its dipole term
 * dot(c - p, A) / |c - p|^3 (A: its summed area vectors), the solid angle of a
 * small patch; nearer leaves add their triangles' exact solid angles. */
kernel void fiv_inside_sphere(global const float4 *wnodes, global const float4 *tris, float4 sphere, int n_theta,
                              int n_phi, float rho, global uchar *inside)
{
    int gid = get_global_id(0);
    if (gid >= n_theta * n_phi)
        return;
    int i = gid / n_phi, j = gid % n_phi;
    float3 d = pn_fiv_direction(PN_PI * (float)i / (float)(n_theta - 1), PN_TWO_PI * (float)j / (float)n_phi);
    float3 p = sphere.xyz - rho * d;
    float sum = 0.0f;
    uint stack[PN_BVH_MAX_DEPTH + 1]; /* a pending right child per level */
    int sp = 0;
    uint node = 0;
    for (;;) {
        global const float4 *w = wnodes + 4 * node;
        float4 ball = w[2];
        float3 to_c = ball.xyz - p;
        float d2 = dot(to_c, to_c);
        uint first = pn_load_w(w), count = pn_load_w(w + 1);
        if (d2 > PN_WINDING_BETA * PN_WINDING_BETA * ball.w * ball.w) {
            sum += dot(to_c, pn_load3(w + 3)) / (d2 * sqrt(d2));
        } else if (count > 0) {
            for (uint t = first; t < first + count; ++t) {
                global const float4 *v = tris + 3 * t;
                sum += pn_triangle_solid_angle(pn_load3(v) - p, pn_load3(v + 1) - p, pn_load3(v + 2) - p);
            }
        } else {
            stack[sp++] = first + 1;
            node = first;
            continue;
        }
        if (sp == 0)
            break;
        node = stack[--sp];
    }
    inside[gid] = fabs(sum) > PN_TWO_PI ? 1 : 0; /* |winding number| = |sum| / 4pi > 1/2, either orientation */
}
