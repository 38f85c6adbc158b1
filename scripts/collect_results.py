"""One summary table over all sessions of a tissue-chain output folder (see scripts/collect-results)."""

import csv
import glob
import json
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

STAGES = [
    ("capture", "capture.mcap"),
    ("fit", "material.mcap"),
    ("diagnose", "diagnosis.json"),
    ("simulate", "sim.mcap"),
]
COLUMNS = [
    "session",
    "status",
    "error",
    "verdict",
    "score",
    "heldout_rmse_before_mm",
    "heldout_rmse_after_mm",
    "params",
    "runner_up",
    "runner_up_score",
]


def last_error(out, session, rule):
    """The last line naming an error in the SLURM log of `rule` for `session` (the plugin's
    .snakemake/slurm_logs/rule_<rule>/<session>/<jobid>.log, under OUT's parent or the current folder)."""
    roots = [out, os.path.dirname(os.path.abspath(out)), "."]
    for root in roots:
        pattern = os.path.join(root, ".snakemake", "slurm_logs", f"rule_{rule}", session, "*.log")
        for path in sorted(glob.glob(pattern), key=os.path.getmtime, reverse=True):
            with open(path, errors="replace") as f:
                lines = [l.strip() for l in f if "error" in l.lower()]
            if lines:
                return lines[-1][:200]
    return ""


def row(out, session):
    r = dict.fromkeys(COLUMNS, "")
    r["session"] = session
    folder = os.path.join(out, session)
    missing = [rule for rule, name in STAGES if not os.path.isfile(os.path.join(folder, name))]
    r["status"] = f"no {dict(STAGES)[missing[0]]}" if missing else "ok"
    if missing:
        r["error"] = last_error(out, session, missing[0])
    path = os.path.join(folder, "diagnosis.json")
    if not os.path.isfile(path):
        return r
    try:
        with open(path) as f:
            d = json.load(f)
        ranked = d["ranked"]
        r["verdict"] = d["verdict"]
        top = next((h for h in ranked if h["hypothesis"] == d["verdict"]), ranked[0])
        r["score"] = f"{top['score']:.4g}"
        r["heldout_rmse_before_mm"] = f"{1e3 * top['heldout_rmse_before_m']:.4f}"
        r["heldout_rmse_after_mm"] = f"{1e3 * top['heldout_rmse_after_m']:.4f}"
        r["params"] = ";".join(f"{k}={v:.4g}" for k, v in sorted(top.get("params", {}).items()))
        others = [h for h in ranked if h is not top]
        if others:
            r["runner_up"] = others[0]["hypothesis"]
            r["runner_up_score"] = f"{others[0]['score']:.4g}"
    except (OSError, ValueError, KeyError, IndexError, TypeError) as e:
        r["status"] = "diagnosis unreadable"
        r["error"] = f"{path}: {e}"
    return r


def plot(rows, path):
    n = len(rows)
    fig, ax = plt.subplots(figsize=(7, 1.2 + 0.45 * n))
    y = list(range(n))[::-1]
    before = [float(r["heldout_rmse_before_mm"] or "nan") for r in rows]
    after = [float(r["heldout_rmse_after_mm"] or "nan") for r in rows]
    ax.barh([v + 0.18 for v in y], before, height=0.36, color="#bbbbbb", label="before (default model)")
    ax.barh([v - 0.18 for v in y], after, height=0.36, color="#3b75af", label="after modeling the verdict")
    labels = []
    for r in rows:
        labels.append(f"{r['session']}\n{r['verdict'] or r['status']}")
    ax.set_yticks(y)
    ax.set_yticklabels(labels, fontsize=8)
    ax.set_xlabel("held-out marker RMSE, mm")
    ax.set_title(f"diagnosis over {n} sessions: verdict and held-out error", fontsize=10)
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=120, format="png")


def main():
    out = sys.argv[1]
    if len(sys.argv) > 2:
        sessions = sorted(
            d for d in os.listdir(sys.argv[2]) if os.path.isfile(os.path.join(sys.argv[2], d, "session.toml"))
        )
    else:
        sessions = sorted(
            d
            for d in os.listdir(out)
            if os.path.isdir(os.path.join(out, d))
            and not d.startswith(".")
            and os.path.isfile(os.path.join(out, d, "capture.mcap"))
        )
    if not sessions:
        sys.exit(f"collect-results: {out}: no session outputs (no <session>/capture.mcap)")
    rows = [row(out, s) for s in sessions]
    csv_path = os.path.join(out, "summary.csv")
    png_path = os.path.join(out, "summary.png")
    for path, write in ((csv_path, lambda f: write_csv(f, rows)), (png_path, lambda f: plot(rows, f))):
        tmp = path + ".tmp"
        write(tmp)
        os.replace(tmp, path)
    ok = sum(r["status"] == "ok" for r in rows)
    print(f"collect-results: {len(rows)} sessions ({ok} ok) -> {csv_path}, {png_path}")


def write_csv(path, rows):
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS)
        w.writeheader()
        w.writerows(rows)


if __name__ == "__main__":
    main()
