/* The material model of docs/brdf.md: Lambert plus a Phong, Blinn-Phong or
 * GGX lobe scaled by k_s. float64 twin: python/penumbra/brdf.py. */
#ifndef PN_COMMON_BRDF_CL
#define PN_COMMON_BRDF_CL

#include "common/math.cl"

#define PN_LOBE_PHONG 0
#define PN_LOBE_BLINN_PHONG 1
#define PN_LOBE_GGX 2
#define PN_MIN_ROUGHNESS 1e-3f
#define PN_MIN_COS_VIEW 1e-4f

/* A G-buffer pixel's material: ALBEDO = (rho, k_s), MATERIAL = (n, alpha, lobe, 0). */
typedef struct {
    float3 albedo;
    float ks;
    float shininess;
    float roughness;
    int lobe;
} pn_material;

inline pn_material pn_material_from_gbuffer(float4 albedo, float4 material)
{
    pn_material m;
    m.albedo = albedo.xyz;
    m.ks = albedo.w;
    m.shininess = material.x;
    m.roughness = clamp(material.y, PN_MIN_ROUGHNESS, 1.0f);
    m.lobe = (int)material.z;
    return m;
}

/* x^e with 0^0 = 1 (a shininess-0 lobe is constant). */
inline float pn_pow0(float x, float e)
{
    return e == 0.0f ? 1.0f : pow(fmax(x, 0.0f), e);
}

inline float pn_ggx_g1(float c, float a2)
{
    return 2.0f * c / (c + sqrt(a2 + (1.0f - a2) * c * c));
}

/* f_lobe(V, L) without k_s, for N.L = nl > 0. */
inline float pn_brdf_lobe(pn_material m, float3 n, float3 v, float3 l, float nl)
{
    float nv = dot(n, v);
    if (m.lobe == PN_LOBE_PHONG) {
        float3 r = 2.0f * nv * n - v;
        return (m.shininess + 2.0f) * PN_INV_TWO_PI * pn_pow0(dot(r, l), m.shininess);
    }
    float3 h = v + l;
    float hl = length(h);
    h = hl > 0.0f ? h / hl : n;
    float nh = fmax(dot(n, h), 0.0f);
    if (m.lobe == PN_LOBE_BLINN_PHONG)
        return (m.shininess + 8.0f) * (0.125f * PN_INV_PI) * pn_pow0(nh, m.shininess);
    float a2 = m.roughness * m.roughness;
    float q = nh * nh * (a2 - 1.0f) + 1.0f;
    float d = a2 * PN_INV_PI / (q * q);
    float cv = fmax(nv, PN_MIN_COS_VIEW);
    return d * pn_ggx_g1(cv, a2) * pn_ggx_g1(nl, a2) / (4.0f * nl * cv);
}

/* f(V, L) per colour channel; zero when N.L <= 0. Skips the lobe when k_s = 0. */
inline float3 pn_brdf(pn_material m, float3 n, float3 v, float3 l)
{
    float nl = dot(n, l);
    if (nl <= 0.0f)
        return (float3)(0.0f);
    float3 f = m.albedo * PN_INV_PI;
    if (m.ks > 0.0f)
        f += m.ks * pn_brdf_lobe(m, n, v, l, nl);
    return f;
}

#endif
