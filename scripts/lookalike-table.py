#!/usr/bin/env python3
"""lookalike-table.py RUN_DIR [CASE ...]: one markdown row per look-alike case run by
scripts/lookalike-chain (capture -> tissue fit -> diagnose with SOFTCAP_DIAGNOSE_PROFILE=1).

Columns: case, protocol, verdict, candidates (held-out fold gains mean +- sd, fitted delay),
next experiment (predicted force/marker difference), the named effect's held-out gains, the
LOOKALIKE margins (paired fold-gain difference verdict - look-alike, in fold spreads: on every
contact frame and after the ramp corners), the chain's CPU-s (user + sys) and the load."""
import json
import re
import statistics
import sys
from pathlib import Path


def ms(g):
    if not g:
        return "-"
    sd = statistics.stdev(g) if len(g) > 1 else 0.0
    return f"{statistics.mean(g):.3f} ± {sd:.3f}"


def params(p):
    return ", ".join(f"{k} {v:.3g}" for k, v in sorted(p.items()))


def row(run: Path, case: str) -> str:
    d = run / case
    log = (d / "log.txt").read_text() if (d / "log.txt").exists() else ""
    n = case.count("-faster-ramps")
    protocol = {0: "standard", 1: "faster-ramps"}.get(n, f"faster-ramps ×{n} (ramps {2 ** n}× as fast)")
    try:
        j = json.loads((d / "diagnosis.json").read_text())
    except (OSError, ValueError):
        return f"| {case} | {protocol} | (no diagnosis) | | | | | | |"
    cands = "; ".join(
        f"{c['hypothesis']} {ms(c['fold_gains'])} ({params(c['params'])})" for c in j.get("candidates", [])
    ) or "-"
    nx = j.get("next_experiment")
    nexts = f"{nx['protocol']} ({nx['predicted_difference_m']:.3g} vs recorded {nx['recorded_difference_m']:.3g})" if nx else "-"
    eff = "; ".join(
        f"{e['hypothesis']} {ms(e['fold_gains'])} ({params(e['params'])})" for e in j.get("effects", [])
    ) or "-"
    look = []
    for m in re.finditer(r"LOOKALIKE \| (\S+) vs (\S+) \| force gains mean / sd of the difference (.*?) \| corner (.*?) \|", log):
        look.append(f"{m[1]}−{m[2]}: all {m[3]}; corner {m[4]}")
    cpu = 0.0
    for m in re.finditer(r"^(capture|fit|diagnose) \S+ wall (\S+) user (\S+) sys", log, re.M):
        cpu += float(m[2]) + float(m[3])
    loads = re.findall(r"load average: ([\d.]+)", log)
    return (
        f"| {case} | {protocol} | {j['verdict']} | {cands} | {nexts} | {eff} | "
        f"{'<br>'.join(look) or '-'} | {cpu:.1f} | {'–'.join(loads[:1] + loads[-1:])} |"
    )


def main():
    run = Path(sys.argv[1])
    cases = sys.argv[2:] or sorted(p.name for p in run.iterdir() if p.is_dir())
    print("| case | protocol | verdict | candidates (fold gains) | next experiment | named effect (fold gains) | LOOKALIKE margin | chain CPU-s | load |")
    print("|---|---|---|---|---|---|---|---|---|")
    for c in cases:
        print(row(run, c))


if __name__ == "__main__":
    main()
