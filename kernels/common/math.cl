/* Shared constants and small helpers for every penumbra kernel (OpenCL C 1.2). */
#ifndef PN_COMMON_MATH_CL
#define PN_COMMON_MATH_CL

#define PN_PI 3.14159265358979323846f
#define PN_TWO_PI 6.28318530717958647692f
#define PN_INV_PI 0.31830988618379067154f
#define PN_INV_TWO_PI 0.15915494309189533577f

/* Marks background pixels and ray misses (matches PN_BACKGROUND in penumbra.h). */
#define PN_BACKGROUND 0xFFFFFFFFu

/* Rotation about +y by an angle given as (cos, sin). */
inline float3 pn_rotate_y(float3 d, float c, float s)
{
    return (float3)(c * d.x + s * d.z, d.y, -s * d.x + c * d.z);
}

inline float pn_luminance(float3 rgb)
{
    return 0.2126f * rgb.x + 0.7152f * rgb.y + 0.0722f * rgb.z;
}

#endif
