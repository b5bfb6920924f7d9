"""chpf-make-bundle: every stage from a mesh to a bundle, sized from a time budget, resumable."""

from __future__ import annotations

import argparse
import shutil
import sys
import time
from pathlib import Path

from chpf.console import run_main
from chpf.errors import ConfigError
from chpf.objects import MESH_UNITS
from make_bundle.plan import MARGIN, Plan, format_plan, make_plan, parse_budget
from make_bundle.state import State


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="chpf-make-bundle", description=__doc__)
    p.add_argument("--object", required=True, help="built-in name (box, mug, ...) or mesh file")
    p.add_argument("--unit", choices=list(MESH_UNITS), default="m", help="unit of a mesh file")
    p.add_argument("--out", required=True, type=Path, help="bundle folder (work in OUT.work)")
    p.add_argument("--budget", default="90m", help="time budget: 90m, 1h30m, 10m, 45s")
    p.add_argument("--preset", choices=["tiny"], help="tiny: a smoke test of every stage")
    p.add_argument("--workers", type=int, default=2, help="render worker processes")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--cache-dir", type=Path, help="pool cache (default OUT.work/cache)")
    p.add_argument("--overwrite", action="store_true", help="start again with other settings")
    p.add_argument("--shard", type=int, help="data stages only: job I of a cluster array")
    p.add_argument("--num-shards", type=int, default=1, help="number M of shard jobs")
    p.add_argument("--no-progress", action="store_true")
    return p


def _stage_table(rows: list[tuple[str, str, str, str]]) -> str:
    out = ["| stage | size | wall s | status |", "| --- | --- | --- | --- |"]
    return "\n".join(out + [f"| {a} | {b} | {c} | {d} |" for a, b, c, d in rows])


def _run_shard(ctx, state: State, settings: dict, shard: int, num_shards: int) -> int:
    """Job ``shard`` of ``num_shards``: its shards of every data stage, nothing else."""
    from chpf.outdir import lock_output_path
    from make_bundle import stages as S

    settings = state.claim(settings)  # every job of the array follows the first one's plan
    state.check_settings(settings, False)
    ctx.plan = Plan(**settings["plan"])
    print("plan:\n" + format_plan(ctx.plan), flush=True)
    ctx.shard = (shard, num_shards)
    job = ctx.work.parent / f"{ctx.work.name}.shard-{shard}-of-{num_shards}"
    with lock_output_path(job, "chpf-make-bundle"):
        for name in S.DATA_STAGES:
            print(f"== {name} (shard {shard} of {num_shards})", flush=True)
            S.STAGE_FNS[name](ctx)
    print(
        f"shard {shard} of {num_shards} done; when every job has finished, run the same "
        "command without --shard to go on to training"
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    from chpf.outdir import lock_output_path
    from data_gen.cli import check_shard_args
    from data_gen.mesh_checks import checked_object

    t_start = time.monotonic()
    argv = list(sys.argv[1:] if argv is None else argv)
    args, trainer_args = build_parser().parse_known_args(argv)
    bad = [a for a in trainer_args if a.startswith("--") and not a.startswith("--trainer.")]
    if bad:
        raise ConfigError(f"unknown option {bad[0]} (only --trainer.* pass through)")
    check_shard_args(args.shard, args.num_shards)
    if args.shard is not None and args.overwrite:
        raise ConfigError("--overwrite: not with --shard (start again in a run without --shard)")
    checked_object(args.object, unit=args.unit)  # bad meshes: one line, before anything runs
    budget = parse_budget(args.budget)
    out = args.out
    work = out.parent / f"{out.name}.work"
    from make_bundle import stages as S

    base = {
        "object": args.object, "unit": args.unit, "budget_s": budget, "preset": args.preset,
        "seed": args.seed, "trainer_args": trainer_args,
    }  # fmt: skip
    old = State(work).settings()
    rates = None
    if old is not None and old.get("base") != base and not args.overwrite:
        State(work).check_settings({"base": base}, False)  # refused before measuring
    if old is not None and old.get("base") == base:  # a rerun: the first run's plan
        plan = Plan(**old["plan"])
        measured = old.get("measured")
    else:
        if args.preset is None:  # the tiny preset has fixed sizes: no measuring
            from make_bundle.measure import measure

            rates = measure(checked_object(args.object, unit=args.unit), 64, trainer_args)
        plan = make_plan(budget, args.preset, rates, args.workers, time.monotonic() - t_start)
        measured = vars(rates) if rates else None
    if measured:
        print(
            f"measured: {measured['renders_per_s']:.0f} renders/s (one process), "
            f"{measured['ae_steps_per_s']:.2f} autoencoder steps/s ({measured['precision']})",
            flush=True,
        )
    settings = {"base": base, "plan": vars(plan), "measured": measured}
    ctx = S.Ctx(
        obj=args.object, unit=args.unit, out=out, work=work, plan=plan,
        workers=args.workers, seed=args.seed, trainer_args=trainer_args,
        progress=not args.no_progress, cache=args.cache_dir or work / "cache",
    )  # fmt: skip
    if args.shard is not None:
        return _run_shard(ctx, State(work), settings, args.shard, args.num_shards)
    print("plan:\n" + format_plan(plan), flush=True)
    with lock_output_path(work, "chpf-make-bundle"):
        state = State(work)
        if state.check_settings(settings, args.overwrite):  # --overwrite: all outputs stale
            for name, _ in S.STAGES:
                S.clean(ctx, name, data_too=True)
        sizes = plan.sizes()
        before = sum(state.done(name)["wall_s"] for name, _ in S.STAGES if state.done(name))
        ctx.deadline = t_start + budget * (1 - MARGIN / 2) - before
        rows = []
        ran = 0
        for name, fn in S.STAGES:
            info = state.done(name)
            if info is not None:
                note = f", {info['note']}" if "note" in info else ""
                rows.append((name, sizes[name], f"{info['wall_s']:.1f}", "done before" + note))
                continue
            S.clean(ctx, name)
            print(f"== {name}: {sizes[name]}", flush=True)
            t0 = time.perf_counter()
            fn(ctx)
            wall = time.perf_counter() - t0
            note = ctx.notes.get(name)
            state.mark(name, {"wall_s": wall, **({"note": note} if note else {})})
            ran += 1
            rows.append((name, sizes[name], f"{wall:.1f}", f"ran, {note}" if note else "ran"))
            print(_stage_table(rows), flush=True)
        if ran == 0 and (out / "report.md").is_file():
            print(_stage_table(rows))
            print(f"nothing to do: {out} is complete")
            return 0
        from data_gen.contact_sheet import contact_sheet

        contact_sheet(work / "pairs", out / "contact_sheet.png", n=24)
        for png in (work / "track").rglob("*.png"):
            shutil.copyfile(png, out / f"track_{png.name}")
        from make_bundle.report import write_report

        total = sum(float(r[2]) for r in rows)
        run_s = time.monotonic() - t_start
        rows.append(("total", f"budget {budget:.0f} s", f"{total:.1f}", f"this run {run_s:.0f} s"))
        table = _stage_table(rows)
        path = write_report(out, work, argv, settings, format_plan(plan), table, args.workers)
        print(table)
        print(f"report -> {path}")
    return 0


cli = run_main(main)

if __name__ == "__main__":
    sys.argv[0] = "chpf-make-bundle"
    cli()
