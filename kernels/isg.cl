/* `isg` method: env lighting as K spherical-Gaussian lobes, occluders as sphere
 * sets, per-pixel diffuse and specular soft shadows by the Integral Spherical
 * Gaussian (Iwasaki et al.; docs/isg.md section 7; float64 twin:
 * tests/isg_shading64.py).
 *
 * For every light lobe G_k and every pixel (p, n):
 *   diffuse  E_k = pn_sg_irradiance(G_k, n) * V(G_k x G_cos)
 *   specular S_k = k_s * pn_sg_irradiance(G_k x G_brdf, n) * V(G_k x G_brdf)
 * where G_cos = G(n, 2.133, 1.170) (the seed's cosine lobe: it only locates
 * the visibility, the unshadowed value is the accurate closed form) and G_brdf
 * is the BRDF lobe as an SG around the mirror direction. V(G) is the visible
 * share of the product lobe: its front hemisphere in the ISG frame, cut to a
 * window of +-PN_ISG_WINDOW_SIGMAS / sqrt(lambda) around the axis (all of it
 * for broad lobes), divided into M x M patches; a patch whose centre direction
 * meets a sphere is occluded (once, however many spheres cover it: a bit
 * mask), and
 *   V = 1 - sum over occluded patches of ISG(patch) / ISG(window)
 * with the ISG from the table of common/sg.cl (the seed's eqs. 5-9), separable
 * in the window: 2 (M + 1) table evaluations per lobe, not 4 per patch.
 * Spheres outside the window's cone (axis angle > window + sphere angle) and
 * behind the receiver plane are culled before any patch work.
 *
 * Self-occlusion (the receiver's own instance's spheres; `self_occlusion`):
 *   0  ignored;
 *   1  used, except spheres that contain the receiver point or touch it
 *      (distance < radius * (1 + PN_ISG_TOUCH)): a receiver on the surface of
 *      its own proxy would otherwise see half its sky cut by the sphere it
 *      sits in (the "dark disc");
 *   2  all used.
 * A sphere of another instance that contains the receiver occludes every
 * patch (the receiver is inside that occluder).
 *
 * Spheres: float4 (world centre, world radius) and the owning instance id. */
#include "common/brdf.cl"
#include "common/sg.cl"
#include "common/sphere_maps.cl"

#define PN_ISG_MAX_GRID 24
#define PN_ISG_MASK_WORDS ((PN_ISG_MAX_GRID * PN_ISG_MAX_GRID + 31) / 32)
#define PN_ISG_WINDOW_SIGMAS 3.0f
#define PN_ISG_TOUCH 1e-3f
/* The seed's cosine lobe (after [WRG*09]). */
#define PN_ISG_COS_SHARPNESS 2.133f
#define PN_ISG_COS_AMPLITUDE 1.170f

/* Half-width of the patch window of a lobe of sharpness lambda. */
inline float pn_isg_window(float lambda)
{
    return fmin(0.5f * PN_PI, PN_ISG_WINDOW_SIGMAS * rsqrt(fmax(lambda, 1e-30f)));
}

/* The visible share of lobe g (unit amplitude used) seen from p with normal n. */
inline float pn_isg_visibility(pn_sg g, float3 p, float3 n, uint self_id, int self_occlusion,
                               global const float4 *spheres, global const uint *owners, int sphere_count, int grid,
                               global const float *table)
{
    float3 x, y;
    pn_sg_frame(g.axis, &x, &y);
    const float w = pn_isg_window(g.sharpness);
    const float lo = 0.5f * PN_PI - w, step = 2.0f * w / (float)grid;
    /* The window's cone: its corners lie within w * sqrt(2) of the axis. */
    const float cone = fmin(w * 1.41421356f, PN_PI), cos_cone = cos(cone), sin_cone = sin(cone);
    float sin_c[PN_ISG_MAX_GRID], cos_c[PN_ISG_MAX_GRID]; /* of the patch centres' angles (theta and phi alike) */
    for (int i = 0; i < grid; ++i) {
        const float a = lo + ((float)i + 0.5f) * step;
        sin_c[i] = sin(a), cos_c[i] = cos(a);
    }
    uint mask[PN_ISG_MASK_WORDS];
    for (int i = 0; i < PN_ISG_MASK_WORDS; ++i)
        mask[i] = 0u;
    int any = 0;
    for (int s = 0; s < sphere_count; ++s) {
        const float4 sp = spheres[s];
        const float3 v = sp.xyz - p;
        const float r = sp.w, d2 = dot(v, v);
        if (dot(v, n) <= -r) /* wholly behind the receiver plane */
            continue;
        const bool own = owners[s] == self_id;
        if (own && self_occlusion == 0)
            continue;
        if (d2 <= r * r * (1.0f + PN_ISG_TOUCH) * (1.0f + PN_ISG_TOUCH)) {
            if (own && self_occlusion == 1)
                continue;
            return 0.0f; /* inside an occluder */
        }
        const float d = sqrt(d2);
        const float3 u = v / d;
        const float sa = fmin(r / d, 1.0f), ca = sqrt(fmax(1.0f - sa * sa, 0.0f));
        /* Outside the window's cone: axis angle > cone + alpha (possible only when cone + alpha < pi). */
        if (cos_cone > -ca && dot(u, g.axis) < cos_cone * ca - sin_cone * sa)
            continue;
        const float alpha = asin(sa);
        const float2 tp = pn_isg_angles(u, x, y, g.axis);
        /* Patch rows and columns the cap can reach (lat-long bounds of a cap). */
        int i0 = (int)floor((tp.x - alpha - lo) / step), i1 = (int)floor((tp.x + alpha - lo) / step);
        int j0, j1;
        const float st = sin(tp.x);
        if (tp.x - alpha <= 0.0f || tp.x + alpha >= PN_PI || sa >= st) {
            j0 = 0, j1 = grid - 1;
        } else {
            const float dphi = asin(fmin(sa / st, 1.0f));
            float ph = tp.y;
            if (ph > 1.5f * PN_PI) /* behind the lobe, on the phi seam side */
                ph -= PN_TWO_PI;
            j0 = (int)floor((ph - dphi - lo) / step), j1 = (int)floor((ph + dphi - lo) / step);
        }
        i0 = max(i0, 0), j0 = max(j0, 0), i1 = min(i1, grid - 1), j1 = min(j1, grid - 1);
        const float3 ul = (float3)(dot(u, x), dot(u, y), dot(u, g.axis));
        for (int i = i0; i <= i1; ++i)
            for (int j = j0; j <= j1; ++j) {
                const float dotc = sin_c[i] * (cos_c[j] * ul.x + sin_c[j] * ul.z) + cos_c[i] * ul.y;
                if (dotc >= ca) {
                    const int b = i * grid + j;
                    mask[b >> 5] |= 1u << (b & 31);
                    any = 1;
                }
            }
    }
    if (!any)
        return 1.0f;
    /* The window lies in the front half (phi <= pi), where the table's ISG is
     * A(theta) B(phi): a patch is (A(t1) - A(t0)) (B(p1) - B(p0)), the four
     * corners of the seed's formula in 2 (M + 1) evaluations. The constant
     * factors A(pi), B(pi) of pn_isg(., pi) cancel in the ratio. */
    const float lambda = g.sharpness;
    float a_prev = pn_isg(lambda, lo, PN_PI, table), b_edge[PN_ISG_MAX_GRID + 1];
    for (int j = 0; j <= grid; ++j)
        b_edge[j] = pn_isg(lambda, PN_PI, lo + (float)j * step, table);
    float occluded = 0.0f;
    const float a_first = a_prev;
    for (int i = 0; i < grid; ++i) {
        const float a_next = pn_isg(lambda, lo + (float)(i + 1) * step, PN_PI, table);
        float row = 0.0f;
        for (int j = 0; j < grid; ++j) {
            const int b = i * grid + j;
            if (mask[b >> 5] & (1u << (b & 31)))
                row += b_edge[j + 1] - b_edge[j];
        }
        occluded += (a_next - a_prev) * row;
        a_prev = a_next;
    }
    const float total = (a_prev - a_first) * (b_edge[grid] - b_edge[0]);
    if (!(total > 0.0f))
        return 1.0f;
    return clamp(1.0f - occluded / total, 0.0f, 1.0f);
}

/* The specular lobe f_lobe (without k_s) as one SG in the light direction:
 * Phong (n + 2)/2pi max(0, R.L)^n ~ (n + 2)/2pi exp(n (R.L - 1)); Blinn-Phong
 * and GGX by the spherical warp of their half-vector lobe to R (Wang et al.
 * 2009): sharpness / (4 N.V), the GGX factor G / (4 N.L N.V) taken at R. */
inline pn_sg pn_isg_brdf_sg(pn_material m, float3 n, float3 view)
{
    const float nv = fmax(dot(n, view), PN_MIN_COS_VIEW);
    pn_sg b;
    b.axis = 2.0f * dot(n, view) * n - view;
    if (m.lobe == PN_LOBE_PHONG) {
        b.sharpness = m.shininess;
        b.amplitude = (float3)((m.shininess + 2.0f) * PN_INV_TWO_PI);
    } else if (m.lobe == PN_LOBE_BLINN_PHONG) {
        b.sharpness = m.shininess / (4.0f * nv);
        b.amplitude = (float3)((m.shininess + 8.0f) * (0.125f * PN_INV_PI));
    } else {
        const float a2 = m.roughness * m.roughness;
        const float nl = fmax(dot(n, b.axis), PN_MIN_COS_VIEW);
        b.sharpness = 2.0f / (a2 * 4.0f * nv);
        b.amplitude = (float3)(PN_INV_PI / a2 * pn_ggx_g1(nv, a2) * pn_ggx_g1(nl, a2) / (4.0f * nl * nv));
    }
    return b;
}

kernel void shade_isg(global const float4 *position, global const float4 *normal, global const float4 *albedo,
                      global const float4 *material, global const uint *instance_id, int count,
                      global const float4 *cube, int n_cube, int show_background, global const float4 *lobes,
                      int lobe_count, global const float4 *spheres, global const uint *owners, int sphere_count,
                      int grid, int self_occlusion, int specular_shadows, float4 camera,
                      global const float *table, global float4 *image)
{
    const int gid = get_global_id(0);
    if (gid >= count)
        return;
    const uint id = instance_id[gid];
    if (id == PN_BACKGROUND) {
        const float3 env = show_background ? pn_cube_texel_lookup(cube, n_cube, normalize(position[gid].xyz))
                                           : (float3)(0.0f);
        image[gid] = (float4)(env, 0.0f);
        return;
    }
    const float3 p = position[gid].xyz;
    const float3 n = normalize(normal[gid].xyz);
    const pn_material m = pn_material_from_gbuffer(albedo[gid], material[gid]);
    pn_sg cosine;
    cosine.axis = n;
    cosine.sharpness = PN_ISG_COS_SHARPNESS;
    cosine.amplitude = (float3)(PN_ISG_COS_AMPLITUDE);
    pn_sg brdf;
    if (m.ks > 0.0f)
        brdf = pn_isg_brdf_sg(m, n, normalize(camera.xyz - p));
    float3 diffuse = (float3)(0.0f), specular = (float3)(0.0f);
    for (int k = 0; k < lobe_count; ++k) {
        const pn_sg g = pn_sg_load(lobes, k);
        const float3 e = pn_sg_irradiance(g, n);
        if (e.x > 0.0f || e.y > 0.0f || e.z > 0.0f)
            diffuse += e * pn_isg_visibility(pn_sg_product(g, cosine), p, n, id, self_occlusion, spheres, owners,
                                             sphere_count, grid, table);
        if (m.ks > 0.0f) {
            const pn_sg gb = pn_sg_product(g, brdf);
            const float3 s = pn_sg_irradiance(gb, n);
            if (s.x > 0.0f || s.y > 0.0f || s.z > 0.0f)
                specular += s * (specular_shadows ? pn_isg_visibility(gb, p, n, id, self_occlusion, spheres, owners,
                                                                      sphere_count, grid, table)
                                                  : 1.0f);
        }
    }
    const float3 c = m.albedo * PN_INV_PI * diffuse + m.ks * specular;
    image[gid] = (float4)(fmax(c, 0.0f), 1.0f);
}
