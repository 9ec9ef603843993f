"""Tolerances of the float32 kernels against float64 references, in one
place with the reason for each (STYLE.md: tolerances kept together)."""

# Direction <-> lat-long / cube mappings: a few float32 ulps of unit vectors.
MAPPING_ATOL = 2e-6
# Round trips through atan2/acos in float32: acos loses precision near the
# poles (d(acos)/dy diverges), so angles are compared, not raw coordinates.
ROUNDTRIP_ANGLE_ATOL = 1e-3 / 180.0 * 3.141592653589793 * 10  # 0.01 degree
# Sums of many float32 solid angles (up to 6*256^2 texels).
SOLID_ANGLE_SUM_RTOL = 1e-5
# Cube radiance against the float64 re-implementation of the same filter.
CUBE_RTOL = 1e-5
# Irradiance sums over 6*F*F float32 terms.
IRRADIANCE_RTOL = 2e-5
# BRDF kernel against float64: pow(x, n) turns the float32 rounding of x
# (~1e-7 relative after the dot products) into n * 1e-7; shininess up to 1000.
BRDF_RTOL = 3e-4
# `reference` pixels against the float64 sum: hundreds of float32 terms, each
# with BRDF rounding as above, and float32 positions and normals.
REFERENCE_RTOL = 1e-4
