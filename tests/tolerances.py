"""Tolerances of the float32 kernels against float64 references, in one
place with the reason for each (STYLE.md: tolerances kept together)."""

# Direction <-> lat-long / cube mappings: a few float32 ulps of unit vectors.
MAPPING_ATOL = 2e-6
# Round trips through atan2/acos in float32: acos loses precision near the
# poles (d(acos)/dy diverges), so angles are compared, not raw coordinates.
ROUNDTRIP_ANGLE_ATOL = 1e-3 / 180.0 * 3.141592653589793 * 10  # 0.01 degree
# Background pixels (bilinear lat-long lookup, envmap_background) against
# the float64 twin (tests/envmap64.py), relative to the map's largest value,
# on maps of random texels (16 x 8 and 64 x 32): float32 atan2/acos and the
# bilinear weights. Measured 9.4e-7 (the device function, seam and poles
# included) and 2.0e-6 (rendered, rotation 30 deg, intensity 2.5). A
# nearest-texel lookup, a half-texel shift or a seam that does not wrap errs
# by 0.1 and more on random texels.
BACKGROUND_ATOL = 2e-5
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
# --- fiv (tests/test_fiv.py against the float64 twin tests/fiv64.py) -------
# Bake samples against the float64 ray cast, times value_scale (the env's
# total power, a bound on every term's sum): each sample is a float32 sum of
# up to 6*8*8 = 384 terms L w dw, whose rounding grows like sqrt(n) eps ~
# 1e-6 of the sum of |terms| <= value_scale. Measured 1.8e-7; a wrong
# channel, axis, solid angle or a dropped direction is >= 1e-3.
FIV_BAKE_ATOL = 4e-6
# `fiv` pixels against the twin, times the largest unshadowed radiance:
# away from the poles float32 trig/log and 8-sample sums give ~1e-6
# (measured 1.0e-6); within ~1e-3 rad of a pole, acos of the float32 d.y
# (1 ulp of 1 = 6e-8) moves theta by a few % of itself, i.e. a few % of the
# weight on the first ring: measured 2.5e-5 there.
FIV_SHADE_ATOL = 5e-5
# Continuity across the phi seam (+-1e-4 rad) and at the poles (1e-3 rad
# away, four azimuths), times the largest value: the lookup is linear there,
# so the change is the angle step times the gradient (measured 7e-5 at the
# seam, 4e-4 at the poles); a seam that does not wrap jumps by > 5e-2.
FIV_CONTINUITY_ATOL = 1e-3
# (rho_max / rho)^2 beyond the grid, occluded E = E0 - E from two float32
# outputs of ~5 (2 ulp ~ 1e-6) against an occluded E of ~0.06 at 4 rho_max:
# <= 2e-5 relative (measured 7e-6).
FIV_FALLOFF_RTOL = 5e-5
# Adding an occluder with overlap 0 (sum of non-negative terms) or 2
# (products of factors in [0, 1]) cannot brighten a pixel; float32 rounding
# is monotonic, so the measured increase is exactly 0. Relative to the
# pixel's unshadowed radiance.
FIV_MONOTONE_ATOL = 1e-6
# overlap 1 (pairwise unit-bounding-disc lens correction) can brighten a pixel
# when an occluder is added: its lens with the others takes back a share of
# their irradiance. Largest increase measured over 20 random placements of
# 1..4 spheres and boxes above a plane: 0.179 of the pixel's unshadowed
# radiance (docs/fiv.md quotes it); the bound leaves room for other seeds.
FIV_OVERLAP_INCREASE_MAX = 0.25
# A uniformly scaled + translated instance against the mesh baked at that
# scale, times the largest radiance: the bakes agree to float32 rounding (the
# same rays hit), the images differ by float32 transforms of centre and v
# (measured 3.9e-7).
FIV_SCALED_INSTANCE_ATOL = 1e-5
# --- depthmap (tests/test_depthmap.py against tests/depthmap64.py) --------
# Map depths against the float64 rasteriser, times the map's depth extent:
# z = far - p.d in float32 from transformed float32 vertices, a few ulps of
# the scene's size (measured below 1e-6); a wrong frame or interpolation is
# off by texels, i.e. >= 1e-2. Lookups whose comparison falls within this of
# the threshold count as ambiguous in the twin (lit or dark).
DEPTHMAP_DEPTH_ATOL = 1e-5
# Shaded pixels against the float64 sum, relative: at most 64 domains x 16
# cap points of float32 BRDF terms (pow(x, n) turns x's rounding into
# n * 1e-7, shininess 50 here), as BRDF_RTOL.
DEPTHMAP_SHADE_RTOL = 3e-4

# isg shading kernel (float32, table ISG and closed-form SG x cosine) against its
# float64 twin (exact ISG by quadrature, exact SG x cosine): the table's ISG
# error is <= 0.004 of the lobe's hemisphere integral and the closed-form cosine
# <= 0.4 % of E(1) (docs/isg.md 3), and a patch whose centre lies within float32
# rounding of a sphere's cap edge may be marked on one side only.
ISG_SHADE_RTOL = 1e-2
ISG_SHADE_ATOL = 1e-2  # times the largest pixel value of the case

# The patch visibility of the lobe x cosine product against the exact visible
# share (dense quadrature, exact ray-sphere tests) at 24 x 24 patches: the
# product-lobe stand-in for lobe x cosine and the patch-centre test.
ISG_VISIBILITY_PATCH_ATOL = 0.05
# The visible share of one lobe by 24 x 24 patches against dense quadrature:
# patch-centre membership along the cap edges (not monotone in M: measured 0.011
# at M = 24 and 0.0045 at M = 16 for lambda = 40) and the window cut at 3 sigma.
ISG_VISIBILITY_GRID_ATOL = 0.02
