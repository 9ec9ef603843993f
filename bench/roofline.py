"""The machine's limits as the OpenCL device sees them: peak FLOP/s of fused
multiply-adds and memory bandwidth (copy, read), under the same runtime the
kernels run on (PoCL on the CPU by default). docs/performance.md compares each
kernel's achieved rates against these two numbers (a roofline).

    python bench/roofline.py [--mib 256] [--reps 7] [--json out.json]

Peak FLOP/s: each work-item runs 8 independent chains of float16
`a = fma(a, b, c)` (2 FLOPs per lane) so that neither latency nor the
vectorizer's packing of work-items into SIMD lanes is the limit. Bandwidth: a float4 copy
(bytes read + written) and a float4 sum (bytes read) over buffers much larger
than the caches. Median of `--reps` runs after one untimed run.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np
import pyopencl as cl

SOURCE = r"""
__kernel void fma_peak(__global float *out, const float b, const float c, const int iters) {
    /* float16 chains: 16 SIMD lanes per work-item whatever the vectorizer does with the work-item loop */
    float16 a0 = (float16)(get_global_id(0) * 1e-7f), a1 = a0 + 1e-3f, a2 = a0 + 2e-3f, a3 = a0 + 3e-3f;
    float16 a4 = a0 + 4e-3f, a5 = a0 + 5e-3f, a6 = a0 + 6e-3f, a7 = a0 + 7e-3f;
    const float16 vb = (float16)(b), vc = (float16)(c);
    for (int i = 0; i < iters; ++i) {
        a0 = fma(a0, vb, vc); a1 = fma(a1, vb, vc); a2 = fma(a2, vb, vc); a3 = fma(a3, vb, vc);
        a4 = fma(a4, vb, vc); a5 = fma(a5, vb, vc); a6 = fma(a6, vb, vc); a7 = fma(a7, vb, vc);
    }
    float16 s = a0 + a1 + a2 + a3 + a4 + a5 + a6 + a7;   /* keeps the chains alive */
    out[get_global_id(0)] = s.s0 + s.s1 + s.s2 + s.s3 + s.s4 + s.s5 + s.s6 + s.s7
                          + s.s8 + s.s9 + s.sa + s.sb + s.sc + s.sd + s.se + s.sf;
}
__kernel void copy4(__global const float4 *src, __global float4 *dst) {
    dst[get_global_id(0)] = src[get_global_id(0)];
}
__kernel void sum4(__global const float4 *src, __global float *out, const int per_item) {
    /* each work-item sums its own contiguous run, 16 floats per load */
    __global const float16 *p = (__global const float16 *)src + get_global_id(0) * (size_t)(per_item / 4);
    float16 s = (float16)(0.0f);
    for (int i = 0; i < per_item / 4; ++i) s += p[i];
    out[get_global_id(0)] = s.s0 + s.s1 + s.s2 + s.s3 + s.s4 + s.s5 + s.s6 + s.s7
                          + s.s8 + s.s9 + s.sa + s.sb + s.sc + s.sd + s.se + s.sf;
}
"""


def timed(queue, launch, reps: int) -> float:
    launch().wait()
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        launch().wait()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def measure(ctx: cl.Context, mib: int = 256, reps: int = 7) -> dict:
    queue = cl.CommandQueue(ctx)
    prg = cl.Program(ctx, SOURCE).build()
    k_fma, k_copy, k_sum = (cl.Kernel(prg, n) for n in ("fma_peak", "copy4", "sum4"))
    dev = ctx.devices[0]
    items, iters = 1 << 12, 4096
    out = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, items * 4)
    t = timed(queue, lambda: k_fma(queue, (items,), None, out, np.float32(0.999999),
                                          np.float32(1e-6), np.int32(iters)), reps)
    flops = items * iters * 8 * 16 * 2 / t
    n4 = mib * (1 << 20) // 16
    src = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, n4 * 16)
    dst = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, n4 * 16)
    cl.enqueue_fill_buffer(queue, src, np.float32(1.0), 0, n4 * 16).wait()
    t_copy = timed(queue, lambda: k_copy(queue, (n4,), None, src, dst), reps)
    per_item = 256
    sums = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, n4 // per_item * 4)
    t_sum = timed(queue, lambda: k_sum(queue, (n4 // per_item,), None, src, sums, np.int32(per_item)), reps)
    # The rates mean nothing if the kernels did not do the work: check their results.
    got = np.empty(n4 // per_item, np.float32)
    cl.enqueue_copy(queue, got, sums).wait()
    copied = np.empty(min(n4, 1 << 16) * 4, np.float32)
    cl.enqueue_copy(queue, copied, dst).wait()
    if not (np.all(got == per_item * 4) and np.all(copied == 1.0)):
        raise RuntimeError("roofline: the bandwidth kernels computed wrong results on this device")
    return {
        "device": dev.name.strip(), "platform": dev.platform.name.strip(),
        "compute_units": dev.max_compute_units,
        "peak_gflops_fma": flops / 1e9,
        "copy_gbs": 2 * n4 * 16 / t_copy / 1e9,
        "read_gbs": n4 * 16 / t_sum / 1e9,
        "buffer_mib": mib,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mib", type=int, default=256, help="buffer size for the bandwidth kernels")
    ap.add_argument("--reps", type=int, default=7)
    ap.add_argument("--json", help="also write the numbers to this file")
    args = ap.parse_args()
    result = measure(cl.create_some_context(interactive=False), args.mib, args.reps)
    for key, value in result.items():
        print(f"{key}: {value:.1f}" if isinstance(value, float) else f"{key}: {value}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f, indent=1)


if __name__ == "__main__":
    main()
