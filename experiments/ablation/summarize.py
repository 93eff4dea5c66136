#!/usr/bin/env python3
"""Summarises an ablation sweep's runs.csv by its `pipeline.repairs` value, over every other
grid axis and seed: runs, errors, joints exact, structure exact, identifiable ARI 1, mean ARI,
and the summed wall time against the default's (when the sweep recorded `seconds`).

Usage: summarize.py results/<name>/runs.csv > results/<name>/summary.md
"""
import csv
import sys


def label(value: str) -> str:
    """`{ split = { enabled = false } }` -> `split off`; `{}` -> `default`."""
    value = value.strip()
    if value == "{}":
        return "all on (default)"
    names = [part.split("=")[0].strip(" {") for part in value.strip("{} ").split("},")]
    return ("all off" if len(names) > 6 else ", ".join(names) + " off")


def main(path: str) -> None:
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    key = "pipeline.repairs"
    order, groups = [], {}
    for r in rows:
        v = r[key]
        if v not in groups:
            order.append(v)
            groups[v] = []
        groups[v].append(r)
    timed = "seconds" in rows[0]
    base_time = sum(float(r["seconds"]) for r in groups[order[0]]) if timed else None
    print("| repairs | runs | errors | joints exact | structure exact | identifiable ARI 1 | mean ARI |"
          + (" time (s) | time / default |" if timed else ""))
    print("|---|---|---|---|---|---|---|" + ("---|---|" if timed else ""))
    for v in order:
        g = groups[v]
        n = len(g)
        errors = sum(1 for r in g if r["error"])
        count = lambda col: sum(1 for r in g if r[col] == "true")
        ident = sum(1 for r in g if r["identifiable_ari"] and float(r["identifiable_ari"]) > 1 - 1e-12)
        aris = [float(r["ari"]) for r in g if r["ari"]]
        mean_ari = sum(aris) / len(aris) if aris else float("nan")
        line = (f"| {label(v)} | {n} | {errors} | {count('joints_exact')} | {count('structure_exact')}"
                f" | {ident} | {mean_ari:.3f} |")
        if timed:
            t = sum(float(r["seconds"]) for r in g)
            line += f" {t:.1f} | {t / base_time:.2f} |"
        print(line)


if __name__ == "__main__":
    main(sys.argv[1])
