"""The source's Table 6: Driving Score on the complete suite vs occlusion-filtered variants.

Runs ``drivee2e bench`` (``bench.run_bench``) once per variant
(``scenario.variants.VARIANTS``: complete, visible_vehicles, visible_all)
with the same policies, then prints and writes a markdown table: DS, SR,
collisions/km per policy and variant, and the share of non-ego agents each
variant removed. Each variant's results folder is ``<out>/<variant>/`` (a
rerun resumes); the visibility masks are computed once per split and cached.

    python experiments/occlusion/table6.py --split val --out results/occlusion
"""

from __future__ import annotations

import argparse
from pathlib import Path

POLICIES = ("log_replay", "expert")


def run(suite: str, split: str, policies: tuple[str, ...], out: Path, limit: int | None, progress: bool) -> dict:
    """{variant: bench summary} (``summary.summarize``)."""
    from drivee2e_jax.eval.bench import BenchConfig, run_bench
    from drivee2e_jax.eval.variants import VARIANTS
    from drivee2e_jax.policy import resolve_policy_path

    paths = tuple(str(resolve_policy_path(p)) for p in policies)
    quiet = lambda line: print(line) if line.startswith(("variant ", "suite ", "[")) else None  # noqa: E731
    return {v: run_bench(BenchConfig(suite=suite, split=split, policies=paths, out=out / v, limit=limit,
                                     variant=v, progress=progress), print_fn=quiet)
            for v in VARIANTS}


def markdown(results: dict, policies: list[str]) -> str:
    """Three tables: DS per variant (the source's layout), DS / SR / collisions
    per km per policy and variant, and the agents each variant removed."""
    variants = list(results)

    def overall(v, pol):
        return results[v]["policies"][pol]["overall"]

    lines = ["| policy | " + " | ".join(f"DS {v}" for v in variants) + " |", "|---|" + "---:|" * len(variants)]
    for pol in policies:
        base = overall(variants[0], pol)["driving_score"]
        cells = [f"{overall(v, pol)['driving_score']:.2f}" + ("" if v == variants[0] else
                 f" ({overall(v, pol)['driving_score'] - base:+.2f})") for v in variants]
        lines.append(f"| {pol} | " + " | ".join(cells) + " |")
    lines += ["", "| policy | variant | DS | SR % | RC | collisions/km |", "|---|---|---:|---:|---:|---:|"]
    for pol in policies:
        for v in variants:
            o = overall(v, pol)
            lines.append(f"| {pol} | {v} | {o['driving_score']:.2f} | {o['success_rate']:.1f} | "
                         f"{o['route_completion']:.2f} | {o['collisions_per_km']:.3f} |")
    lines += ["", "| variant | non-ego agents removed | % | by category (removed / total) |", "|---|---:|---:|---|"]
    counted = [results[v]["run"].get("variant_removed", {}) for v in variants]
    n = max((sum(b for _, b in by.values()) for by in counted), default=0)  # complete records no counts
    for v, by in zip(variants, counted):
        r = sum(a for a, _ in by.values())
        cats = ", ".join(f"{c} {a}/{b}" for c, (a, b) in by.items() if b) or "-"
        lines.append(f"| {v} | {r} / {n} | {100.0 * r / n if n else 0.0:.1f} | {cats} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--suite", default="twin15")
    ap.add_argument("--split", default="val")
    ap.add_argument("--policy", action="append", dest="policies", help=f"repeatable (default: {', '.join(POLICIES)})")
    ap.add_argument("--out", type=Path, default=Path("results/occlusion"))
    ap.add_argument("--limit", type=int, default=None, help="only the first N scenarios (a quick check)")
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    policies = tuple(args.policies or POLICIES)
    results = run(args.suite, args.split, policies, args.out, args.limit, not args.no_progress)
    names = list(results["complete"]["policies"])
    n = results["complete"]["run"]["num_scenarios"]
    table = markdown(results, names)
    text = f"{args.suite} {args.split}, {n} scenarios\n\n{table}\n"
    print("\n" + text)
    from drivee2e_jax.files import atomic_write_json, atomic_write_text

    atomic_write_text(args.out / "table6.md", text)
    atomic_write_json(args.out / "table6.json", {v: {"run": s["run"], "overall": {p: s["policies"][p]["overall"]
                                                                              for p in names}}
                                                for v, s in results.items()})
    print(f"written: {args.out / 'table6.md'}, {args.out / 'table6.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
