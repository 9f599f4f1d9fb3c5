r'''Per-image overhead of the external renderer protocol: one-shot vs persistent

SYNOPSIS

    uv run python benchmarks/bench_command_protocol.py [--n 10] [--size 640 480] [--K 4]
        [--out benchmarks/results/command_protocol.json]

examples/external_renderer.py (it renders with the ray caster) renders the
same board pose n times through the `command` renderer, one process per image
(one-shot) and one process for all (persistent, the first image is left out:
it starts the program), as 16-bit PNG and as .npy. The same renders in this
process through RaycastRenderer are the reference: overhead per image =
median(external wall seconds) - median(in-process seconds). The overhead is
what the protocol costs: process start and imports (one-shot only), writing
the request (model file, scene.json), the program reading it, writing and
reading the image.

The machine is shared: the load average is recorded with the results.
'''

import argparse
import json
import os
import statistics
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tests"))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10)
    ap.add_argument("--size", type=int, nargs=2, default=(640, 480))
    ap.add_argument("--K", type=int, default=4)
    ap.add_argument("--out", default=None)
    args = ap.parse_args()

    from render_checks import board_pose, grid_board, small_model

    from renderers.base import RenderSettings, get_renderer

    W, H = args.size
    model = small_model("CAHVORE", W=W, H=H, f=0.9 * W)
    pattern, _ = grid_board()
    Rt = board_pose(20, 1.0)
    settings = RenderSettings(spp=args.K)
    example = [sys.executable, os.path.join(ROOT, "examples", "external_renderer.py")]

    def times(renderer, n, skip_first):
        out = []
        for _ in range(n + (1 if skip_first else 0)):
            t0 = time.perf_counter()
            renderer.render(model, pattern, Rt, settings)
            out.append(time.perf_counter() - t0)
        return out[1:] if skip_first else out

    ref = times(get_renderer("raycast"), args.n, skip_first=True)
    results = {"in-process raycast": {"median_s": statistics.median(ref)}}
    for fmt in ("png16", "npy"):
        for persistent in (False, True):
            r = get_renderer("command", command=example, output_format=fmt,
                             persistent=persistent)
            try:
                t = times(r, args.n, skip_first=persistent)
            finally:
                r.close()
            med = statistics.median(t)
            results[f"{'persistent' if persistent else 'one-shot'} {fmt}"] = {
                "median_s": med, "overhead_s": med - results["in-process raycast"]["median_s"]}
    for fmt in ("png16", "npy"):
        one = results[f"one-shot {fmt}"]["overhead_s"]
        per = results[f"persistent {fmt}"]["overhead_s"]
        results[f"overhead ratio {fmt}"] = one / per if per > 0 else float("inf")
    doc = {"camera": f"CAHVORE {W}x{H}", "K": args.K, "n": args.n,
           "loadavg": os.getloadavg(), "results": results}
    for k, v in results.items():
        if isinstance(v, dict):
            extra = f", overhead {v['overhead_s'] * 1000:8.1f} ms" if "overhead_s" in v else ""
            print(f"{k:24s} {v['median_s'] * 1000:8.1f} ms per image{extra}")
        else:
            print(f"{k:24s} {v:8.1f}x")
    print(f"load average {doc['loadavg']}")
    if args.out:
        os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
        with open(args.out, "w") as f:
            json.dump(doc, f, indent=1)


if __name__ == "__main__":
    main()
