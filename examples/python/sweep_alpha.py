"""Sweep α over a dataset and plot car AP_3D@0.7 (moderate) per case: the paper's robustness
study (Table II, Fig. 5) on your own data, as a script.

    pip install ./python matplotlib
    python examples/python/sweep_alpha.py --dataset sample_data --samples 4 --out sweep.png

Each point is `Dataset.evaluate`, i.e. exactly what `mlod eval --case CASE --alpha A --seed S
--samples N --json` prints; the perturbation is one draw per seed, the same for every sample (as
on one car).
"""

import argparse

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import mlod  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", default="sample_data")
    ap.add_argument("--cases", default="top,input,mlod-i")
    ap.add_argument("--alphas", default="0,0.05,0.1,0.2")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--samples", type=int, default=None, help="the first N samples (default: all)")
    ap.add_argument("--out", default="sweep.png")
    args = ap.parse_args()

    ds = mlod.open(args.dataset)
    alphas = [float(a) for a in args.alphas.split(",")]
    fig, ax = plt.subplots(figsize=(6, 4))
    for case in args.cases.split(","):
        aps = []
        for alpha in alphas:
            report = ds.evaluate(case, alpha=alpha, seed=args.seed, samples=args.samples)
            ap_car = report["kitti"]["car"]["iou_0.7"]["moderate"]
            aps.append(ap_car)
            print(f"{case:>8}  alpha {alpha:<5}  car AP3D@0.7 moderate {ap_car:6.2f}")
        ax.plot(alphas, aps, marker="o", label=case)
    ax.set_xlabel("α (perturbation of the auxiliary LiDARs)")
    ax.set_ylabel("car AP$_{3D}$@0.7, moderate")
    ax.set_title(f"{args.dataset}: {report['samples']} samples, seed {args.seed}")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(args.out, dpi=120)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
