"""A/B of two builds of libpenumbra (kernels embedded) in alternating subprocesses: CPU time per frame.
usage: ab.py scene rounds frames libA libB [json params] [build options]"""
import json, os, statistics, subprocess, sys, time

if sys.argv[1] == "--worker":
    scene, frames, params = sys.argv[2], int(sys.argv[3]), json.loads(sys.argv[4])
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))  # hf_setup.py
    from hf_setup import terrain
    from penumbra import Renderer
    t = terrain(scene)
    ctx, built, gb, img = t.ctx, t.built, t.gb, t.img
    r = Renderer(ctx, "heightfield", **params)
    r.execute(built.scene, gb, img); ctx.finish()
    cs, ts = [], []
    for _ in range(frames):
        t0, c0 = time.perf_counter(), time.process_time()
        r.execute(built.scene, gb, img); ctx.finish()
        cs.append(1000 * (time.process_time() - c0)); ts.append(1000 * (time.perf_counter() - t0))
    print(json.dumps(dict(cpu=cs, wall=ts)))
    sys.exit(0)
scene, rounds, frames, libs = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4:6]
params = sys.argv[6] if len(sys.argv) > 6 else "{}"
res = {l: dict(cpu=[], wall=[]) for l in libs}
print("load", os.getloadavg())
for k in range(rounds):
    for l in (libs if k % 2 == 0 else libs[::-1]):
        env = dict(os.environ, PENUMBRA_LIBRARY=l)
        out = subprocess.run([sys.executable, __file__, "--worker", scene, str(frames), params], env=env,
                             capture_output=True, text=True, check=True).stdout
        d = json.loads(out.strip().splitlines()[-1])
        res[l]["cpu"] += d["cpu"]; res[l]["wall"] += d["wall"]
a, b = (statistics.median(res[l]["cpu"]) for l in libs)
aw, bw = (statistics.median(res[l]["wall"]) for l in libs)
print(f"{scene} {params}: cpu A {a:.1f} B {b:.1f} A/B {a / b:.3f}   wall A {aw:.1f} B {bw:.1f} A/B {aw / bw:.3f}")
print("load", os.getloadavg())
