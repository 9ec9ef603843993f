/* The material model of docs/brdf.md: Lambert plus a Phong, Blinn-Phong,
 * GGX or anisotropic Ashikhmin-Shirley lobe scaled by k_s. float64 twin:
 * python/penumbra/brdf.py. */
#ifndef PN_COMMON_BRDF_CL
#define PN_COMMON_BRDF_CL

#include "common/math.cl"

#define PN_LOBE_PHONG 0
#define PN_LOBE_BLINN_PHONG 1
#define PN_LOBE_GGX 2
#define PN_LOBE_ASHIKHMIN_SHIRLEY 3
#define PN_MIN_ROUGHNESS 1e-3f
#define PN_MIN_COS_VIEW 1e-4f

/* A G-buffer pixel's material: ALBEDO = (rho, k_s), MATERIAL = (n, alpha, lobe, 0)
 * or, Ashikhmin-Shirley, (n_u, n_v, 3, tangent angle phi). */
typedef struct {
    float3 albedo;
    float ks;
    float shininess;   /* n; n_u for Ashikhmin-Shirley */
    float roughness;
    int lobe;
    float shininess_v; /* n_v (Ashikhmin-Shirley only) */
    float2 tangent;    /* (cos phi, sin phi): u = cos phi t + sin phi b, (t, b) = pn_frame(n) */
} pn_material;

inline pn_material pn_material_from_gbuffer(float4 albedo, float4 material)
{
    pn_material m;
    m.albedo = albedo.xyz;
    m.ks = albedo.w;
    m.shininess = material.x;
    m.lobe = (int)material.z;
    const bool aniso = m.lobe == PN_LOBE_ASHIKHMIN_SHIRLEY;
    m.roughness = aniso ? 1.0f : clamp(material.y, PN_MIN_ROUGHNESS, 1.0f);
    m.shininess_v = aniso ? material.y : 0.0f;
    float s, c;
    s = sincos(aniso ? material.w : 0.0f, &c);
    m.tangent = (float2)(c, s);
    return m;
}

/* The G-buffer's tangent angle of a direction `a` (any length, need not lie
 * in the tangent plane): its angle from t towards b, (t, b) = pn_frame(n);
 * 0 when a is along n (no tangent direction: t is used). */
inline float pn_tangent_angle(float3 n, float3 a)
{
    float3 t, b;
    pn_frame(n, &t, &b);
    const float x = dot(a, t), y = dot(a, b);
    return x == 0.0f && y == 0.0f ? 0.0f : atan2(y, x);
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

/* Ashikhmin-Shirley (2000) specular without its Fresnel factor (k_s is the
 * constant reflectance, as for GGX): sqrt((n_u + 1)(n_v + 1)) / (8 pi)
 * (N.H)^e / ((H.L) max(N.L, N.V)), e = (n_u (H.u)^2 + n_v (H.w)^2) / (1 - (N.H)^2),
 * u the tangent and w = n x u. */
inline float pn_as_lobe(pn_material m, float3 n, float3 l, float nl, float nv, float3 h, float nh)
{
    float3 t, b;
    pn_frame(n, &t, &b);
    const float3 u = m.tangent.x * t + m.tangent.y * b;
    const float3 w = cross(n, u);
    const float hu = dot(h, u), hw = dot(h, w);
    /* (H.u)^2 + (H.w)^2 = 1 - (N.H)^2, taken from the tangent components (no cancellation near H = N). */
    const float den = hu * hu + hw * hw;
    const float e = den > 0.0f ? (m.shininess * hu * hu + m.shininess_v * hw * hw) / den : m.shininess;
    const float hl = fmax(dot(h, l), PN_MIN_COS_VIEW);
    const float cv = fmax(nv, PN_MIN_COS_VIEW);
    return sqrt((m.shininess + 1.0f) * (m.shininess_v + 1.0f)) * (0.125f * PN_INV_PI) * pn_pow0(nh, e) /
           (hl * fmax(nl, cv));
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
    if (m.lobe == PN_LOBE_ASHIKHMIN_SHIRLEY)
        return pn_as_lobe(m, n, l, nl, nv, h, nh);
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
