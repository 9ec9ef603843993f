/* The row search's atan, three variants behind HF_ATAN_EXP (measurement only; none kept):
 * 1: no atan at all (wrong horizons: what the atan costs at most), 2: the reciprocal by native_recip,
 * 3: the 5-term polynomial of Abramowitz and Stegun 4.4.49 (max error 1e-5 rad). */
#if HF_ATAN_EXP == 1
inline hf_rf hf_atan_r(hf_rf x) { return x; }
#elif HF_ATAN_EXP == 2
inline hf_rf hf_atan_r(hf_rf x)
{
    const hf_rf a = fabs(x), t = select(a, native_recip(a), a > 1.0f), t2 = t * t;
    hf_rf p;
    PN_ATAN_POLY(p, t2);
    const hf_rf r = t * p;
    return copysign(select(r, M_PI_2_F - r, a > 1.0f), x);
}
#elif HF_ATAN_EXP == 3
inline hf_rf hf_atan_r(hf_rf x)
{
    const hf_rf a = fabs(x), t = select(a, 1.0f / a, a > 1.0f), t2 = t * t;
    hf_rf p = 0.0208351f;
    p = p * t2 - 0.085133f;
    p = p * t2 + 0.180141f;
    p = p * t2 - 0.3302995f;
    p = p * t2 + 0.999866f;
    const hf_rf r = t * p;
    return copysign(select(r, M_PI_2_F - r, a > 1.0f), x);
}
#else
HF_DEFINE_ATAN(hf_atan_r, hf_rf)
#endif
