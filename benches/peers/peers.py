"""The peers' side of the comparison (run by benches/peers/run.sh; README beside it).

  peers.py time TASK DIR REPS [RESULT]   times the peer on DIR's inputs (written by
                                         `peers export DIR`), prints one JSON line
  peers.py table DIR                     the table of DIR/times.jsonl and the result files

The peers are used as libraries, from the same inputs, starts and tolerances as evitrack.
"""

import json
import math
import statistics
import sys
import time
import warnings

import numpy as np

PEERS = {
    "dempster_fixed": "pybelief 0.1.0",
    "dempster_seed5": "pybelief 0.1.0",
    "em": "hmmlearn 0.3.3",
    "em_log": "hmmlearn 0.3.3 (log)",
    "gp_1start": "scikit-learn 1.9.1",
    "gp_2starts": "scikit-learn 1.9.1",
}


def repeat(reps, run):
    """Seconds of `reps` calls after one warm-up call, and the last result."""
    last = run()
    seconds = []
    for _ in range(reps):
        t = time.perf_counter()
        last = run()
        seconds.append(time.perf_counter() - t)
    return seconds, last


def dempster(inputs, reps):
    from pybelief import MassFunction

    n = inputs["n"]
    frame = [f"e{i}" for i in range(n)]
    fs = [
        MassFunction(frame, {int(s, 16): m for s, m in zip(f["sets"], f["masses"])})
        for f in inputs["functions"]
    ]

    def run():
        # What evitrack's bench times: Dempster's rule over the 8 functions, then the contour.
        combined = fs[0]
        for f in fs[1:]:
            combined = combined & f
        contour = [combined.plausibility(1 << i) for i in range(n)]
        return combined, contour

    seconds, (combined, contour) = repeat(reps, run)
    focal = combined.focal_elements
    focal = focal() if callable(focal) else focal
    sets = [format(k, "x") for k in focal]
    return seconds, {"sets": sets, "masses": list(focal.values()), "contour": contour}


def em(inputs, reps, implementation):
    from hmmlearn.hmm import GaussianHMM

    k = inputs["n_states"]

    def fit_one(feature):
        x = np.asarray(feature["values"]).reshape(-1, 1)
        best = None
        # evitrack's own starts (its restarts, duplicates dropped), its tolerance per
        # observation turned into hmmlearn's absolute one, no priors: plain maximum likelihood.
        for start in feature["starts"]:
            m = GaussianHMM(
                n_components=k,
                covariance_type="diag",
                n_iter=inputs["max_iterations"],
                tol=inputs["tolerance_per_observation"] * len(x),
                init_params="",
                params="stmc",
                covars_prior=0.0,
                covars_weight=1.0,
                implementation=implementation,
            )
            m.startprob_ = np.asarray(start["initial"])
            m.transmat_ = np.asarray(start["transitions"])
            m.means_ = np.asarray(start["means"]).reshape(-1, 1)
            m.covars_ = np.asarray(start["variances"]).reshape(-1, 1)
            m.fit(x)
            ll = m.score(x)
            if best is None or ll > best[0]:
                best = (ll, m.monitor_.iter)
        return best

    def run():
        return [fit_one(f) for f in inputs["features"]]

    seconds, fits = repeat(reps, run)
    return seconds, {"log_likelihood": [f[0] for f in fits], "iterations": [f[1] for f in fits]}


def gp(inputs, reps, starts):
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel

    # A length scale at its bound of 1000 is a feature the kernel ignores, as evitrack's does.
    warnings.filterwarnings("ignore", category=ConvergenceWarning)
    x, y = np.asarray(inputs["inputs"]), np.asarray(inputs["outputs"])
    dim = x.shape[1]

    def run():
        best = None
        # evitrack's starts: length scale × 4^(±⌈s/2⌉), σf = 1, σn = initial_noise; the same
        # bounds (ℓ in [0.01, 1000], σf in [1e-3, 1e3]); one kernel shared by x and y, whose
        # log marginal likelihoods scikit-learn sums as evitrack does.
        for s in range(starts):
            power = math.ceil(s / 2) * (-1 if s % 2 == 1 else 1)
            ell = inputs["initial_length_scale"] * 4.0**power
            kernel = ConstantKernel(1.0, (1e-6, 1e6)) * RBF([ell] * dim, (1e-2, 1e3)) + WhiteKernel(
                inputs["initial_noise"] ** 2, (1e-12, 1e2)
            )
            g = GaussianProcessRegressor(kernel, n_restarts_optimizer=0, normalize_y=False)
            g.fit(x, y)
            if best is None or g.log_marginal_likelihood_value_ > best.log_marginal_likelihood_value_:
                best = g
        return best

    seconds, g = repeat(reps, run)
    mean = g.predict(np.asarray(inputs["test_inputs"]))
    predictions = mean * np.asarray(inputs["output_scales"]) + np.asarray(inputs["output_means"])
    return seconds, {
        "log_marginal_likelihood": float(g.log_marginal_likelihood_value_),
        "kernel": str(g.kernel_),
        "predictions": predictions.tolist(),
    }


def time_task(task, folder, reps, result):
    if task.startswith("dempster"):
        seconds, value = dempster(load(f"{folder}/{task}.json"), reps)
    elif task in ("em", "em_log"):
        # `em`: hmmlearn's faster scaling implementation; `em_log`: its default, in log space.
        implementation = "scaling" if task == "em" else "log"
        seconds, value = em(load(f"{folder}/em.json"), reps, implementation)
    elif task in ("gp_1start", "gp_2starts"):
        seconds, value = gp(load(f"{folder}/gp.json"), reps, 1 if task == "gp_1start" else 2)
    else:
        sys.exit(f"unknown task {task}")
    if result:
        with open(result, "w") as f:
            json.dump(value, f)
    print(json.dumps({"task": task, "who": "peer", "seconds": seconds}))


def load(path):
    with open(path) as f:
        return json.load(f)


def agreement(task, ours, peer, folder):
    """What both computed, side by side (evitrack first)."""
    if task.startswith("dempster"):
        a = {int(s, 16): m for s, m in zip(ours["sets"], ours["masses"])}
        b = {int(s, 16): m for s, m in zip(peer["sets"], peer["masses"])}
        dm = max(abs(a.get(s, 0.0) - b.get(s, 0.0)) for s in a.keys() | b.keys())
        dc = max(abs(p - q) for p, q in zip(ours["contour"], peer["contour"]))
        return f"{len(a)} / {len(b)} focal sets; max abs diff: masses {dm:.1e}, contour {dc:.1e}"
    if task.startswith("em"):
        la, lb = ours["log_likelihood"], peer["log_likelihood"]
        d = [p - q for p, q in zip(la, lb)]
        worst = max(d, key=abs)
        return (
            f"log-lik. summed over 8 features {sum(la):.4f} / {sum(lb):.4f} "
            f"(largest per-feature diff {worst:+.1e}); iterations {sum(ours['iterations'])} / "
            f"{sum(peer['iterations'])}"
        )
    poses = np.asarray(load(f"{folder}/gp.json")["test_poses"])
    pa, pb = np.asarray(ours["predictions"]), np.asarray(peer["predictions"])

    def rms(p):
        return math.sqrt(np.mean(np.sum((p - poses) ** 2, axis=1)))

    return (
        f"log marg. lik. {ours['log_marginal_likelihood']:.2f} / "
        f"{peer['log_marginal_likelihood']:.2f}; test RMS error {rms(pa):.4f} / {rms(pb):.4f} mm; "
        f"predictions differ by at most {np.max(np.abs(pa - pb)):.1e} mm"
    )


def fmt(seconds):
    if seconds < 1e-3:
        return f"{seconds * 1e6:.1f} µs"
    if seconds < 1:
        return f"{seconds * 1e3:.2f} ms"
    return f"{seconds:.3f} s"


def table(folder):
    times = {}
    with open(f"{folder}/times.jsonl") as f:
        for line in f:
            row = json.loads(line)
            times.setdefault((row["task"], row["who"]), []).extend(row["seconds"])
    print("| task | evitrack median | peer | peer median | ratio | agreement (evitrack / peer) |")
    print("|---|---|---|---|---|---|")
    for task, peer_name in PEERS.items():
        if (task, "evitrack") not in times or (task, "peer") not in times:
            continue
        ours = statistics.median(times[(task, "evitrack")])
        theirs = statistics.median(times[(task, "peer")])
        try:
            agree = agreement(
                task,
                load(f"{folder}/result-{task}-evitrack.json"),
                load(f"{folder}/result-{task}-peer.json"),
                folder,
            )
        except (OSError, ValueError, KeyError) as e:
            agree = f"(no agreement: {e})"
        print(
            f"| {task} | {fmt(ours)} | {peer_name} | {fmt(theirs)} | {theirs / ours:.1f}× | {agree} |"
        )


def main(argv):
    if len(argv) >= 4 and argv[0] == "time":
        time_task(argv[1], argv[2], int(argv[3]), argv[4] if len(argv) > 4 else None)
    elif len(argv) == 2 and argv[0] == "table":
        table(argv[1])
    else:
        sys.exit(__doc__)


if __name__ == "__main__":
    main(sys.argv[1:])
