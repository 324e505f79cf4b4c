"""Command line: ``python -m benchmarks [NAME ...] [--quick] [--gpu] [--dtype ...] [--out BENCHMARKS.md]`` runs the
benchmarks in this process (progress on stderr) and writes the report, rewritten after every row, so that a run cut
short keeps every row it finished; x64 is on before anything touches JAX."""

from __future__ import annotations

import argparse
import os
import pathlib
import sys
import textwrap
from collections.abc import Sequence

from . import (ACCELERATOR_BUDGET_S, ACCELERATOR_SECTIONS, ACCELERATOR_TOTAL_S, REGISTRY, BenchConfig, Table,
               default_data_dir, run_benchmarks)
from .report import collect_environment, render_report

#: What ``--gpu`` runs on an accelerator (issue 29; each module's ``ACCELERATOR_*`` sizes, checked by a test).
ACCELERATOR_SIZES_TEXT = (
    "FK of 1,024, 131,072 and 1,048,576 poses; IK of 1,024, 16,384 and 131,072 problems (the own LM first, the "
    "others at 1,024); physics of 1,024 and 65,536 characters, MJX beside it at 65,536 on the same device; SAMCON "
    "at 4,096 samples and the 4 s walk at 1,024; motion-matching searches of 1,024 and 16,384 agents and a crowd of "
    "16,384; skinning of 10^4 vertices x 10^4 frames; DARE of 1,024 to 10^5 systems; pendulum and cart-pole "
    "swing-ups of 16,384")


def _budget_text(budgets: dict[str, float], names: Sequence[str]) -> str:
    return ", ".join(f"{n} {budgets[n]:g} s" for n in names if n in budgets)


def _parser() -> argparse.ArgumentParser:
    names = "\n".join(f"  {s.name:10s} {s.description}" for s in REGISTRY.values())
    p = argparse.ArgumentParser(
        prog="python -m benchmarks",
        description="Benchmark jaxanim against its peers and write BENCHMARKS.md.",
        epilog=f"registered benchmarks:\n{names}\n\n" + textwrap.fill(
            f"--gpu runs {', '.join(ACCELERATOR_SECTIONS)} unless names are given, each within its time budget: "
            f"{_budget_text(ACCELERATOR_BUDGET_S, list(ACCELERATOR_SECTIONS))} (sum "
            f"{sum(ACCELERATOR_BUDGET_S[n] for n in ACCELERATOR_SECTIONS):g} s), and "
            f"{_budget_text(ACCELERATOR_BUDGET_S, [n for n in REGISTRY if n not in ACCELERATOR_SECTIONS])} when "
            f"named (--section-budget changes them), and the run within {ACCELERATOR_TOTAL_S:g} s in all "
            "(--total-budget): a section gets at most what is left of it. A budget is cooperative: a row expected "
            "to end past its section's budget (from the previous batch, else the same batch in another dtype, else "
            "the table's median row) is not started and says so, sampling stops at it, and a row that started in "
            "time runs to its end. The report is rewritten after every row, so a run cut short keeps every row it "
            "finished.", 100),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    arg = p.add_argument
    arg("names", nargs="*", metavar="NAME", help="benchmarks to run (default: all registered; with --gpu: "
        + ", ".join(ACCELERATOR_SECTIONS) + ")")
    arg("--quick", action="store_true", help="batches 1 and 8, 3 repeats, loops capped at 8: a smoke test")
    arg("--gpu", action="store_true", help=f"the accelerator sizes: {ACCELERATOR_SIZES_TEXT}; 5 repeats, 1 "
        "warm-up, 8 s per row, loops capped at 512, each section within its time budget (below). Without an "
        "accelerator it says so and runs the small sizes (those of a run without --gpu; with --quick the quick "
        "ones) within the same budgets")
    arg("--section-budget", type=str, default=None, metavar="SECONDS|NAME=SECONDS,...",
        help="time budget of every section (a number) or of the named ones (default: none; with --gpu the "
        "budgets below)")
    arg("--total-budget", type=float, default=None, metavar="SECONDS", help="time budget of the whole run: each "
        f"section gets at most what is left of it (default: none; with --gpu {ACCELERATOR_TOTAL_S:g})")
    arg("--dtype", choices=("float32", "float64", "both"), default="both", help="default: both")
    arg("--out", type=pathlib.Path, default=pathlib.Path("BENCHMARKS.md"), help="default: BENCHMARKS.md")
    arg("--batches", type=str, default=None, help="comma-separated batch sizes, overriding every benchmark's")
    arg("--repeats", type=int, default=None, help="timed samples per row (default 7, quick 3, gpu 5)")
    arg("--warmup", type=int, default=None, help="untimed calls per row (default 2, quick and gpu 1)")
    arg("--loop-cap", type=int, default=None, help="max configurations per timed Python-loop call (default 2048, "
        "gpu 512)")
    arg("--only", type=str, default=None, help="comma-separated shell patterns: run only the implementations whose "
        "name matches one, case-insensitive (e.g. 'jaxanim*,pinocchio*')")
    arg("--data-dir", type=pathlib.Path, default=None, help=f"shared data folder (default {default_data_dir()})")
    arg("--quiet", action="store_true", help="no progress on stderr")
    return p


def parse_budgets(spec: str | None, gpu: bool, names: Sequence[str]) -> dict[str, float] | None:
    """Each named section's time budget (s): the ``--gpu`` defaults if ``gpu``, then ``spec`` (``"60"`` for every
    section, ``"fk=30,ik=90"`` for some, or both: ``"60,fk=30"``); ``None`` if no section has one.

    Raises:
        ValueError: on a malformed entry, an unknown name or a budget that is not positive.
    """
    budgets = dict(ACCELERATOR_BUDGET_S) if gpu else {}
    for part in (x.strip() for x in (spec or "").split(",")):
        if not part:
            continue
        name, eq, value = part.rpartition("=")
        try:
            seconds = float(value)
        except ValueError:
            raise ValueError(f"--section-budget: expected SECONDS or NAME=SECONDS, got {part!r}") from None
        if not seconds > 0:
            raise ValueError(f"--section-budget: expected a positive number of seconds, got {part!r}")
        if eq and name.strip() not in REGISTRY:
            raise ValueError(f"--section-budget: unknown benchmark {name.strip()!r}; registered: {', '.join(REGISTRY)}")
        budgets.update({name.strip(): seconds} if eq else dict.fromkeys(REGISTRY, seconds))
    chosen = {n: budgets[n] for n in names if n in budgets}
    return chosen or None


def _writer(path: pathlib.Path, env: dict[str, str], command: str, settings: dict[str, str]):
    """``write(tables)``: the report of ``tables`` to ``path``, replaced whole (a kill mid-write leaves the old)."""
    def write(tables: list[Table]) -> None:
        tmp = path.with_name(path.name + ".part")
        tmp.write_text(render_report(env, command, settings, tables), encoding="utf-8")
        os.replace(tmp, path)

    return write


def main(argv: Sequence[str] | None = None) -> int:
    """Parse ``argv``, run the benchmarks, write the report; return the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args = _parser().parse_args(argv)
    unknown = [n for n in args.names if n not in REGISTRY]
    if unknown:
        _parser().error(f"unknown benchmark(s) {unknown}; registered: {', '.join(REGISTRY)}")
    names = list(args.names) or list(ACCELERATOR_SECTIONS if args.gpu else REGISTRY)
    try:
        budgets = parse_budgets(args.section_budget, args.gpu, names)
    except ValueError as exc:
        _parser().error(str(exc))
    total_s = args.total_budget if args.total_budget is not None else ACCELERATOR_TOTAL_S if args.gpu else None
    if total_s is not None and not total_s > 0:
        _parser().error(f"--total-budget: expected a positive number of seconds, got {total_s:g}")

    import jax

    jax.config.update("jax_enable_x64", True)  # float64 rows and references; float32 rows are explicit
    backend = jax.default_backend()
    accelerator = args.gpu and backend != "cpu"
    if args.gpu and not accelerator:  # said even with --quiet
        print(f"[benchmarks] no accelerator found (jax backend: {backend}): running the small sizes (those of a run "
              f"without --gpu{', quick' if args.quick else ''}) within the --gpu section time budgets",
              file=sys.stderr, flush=True)

    kw = {k: v for k in ("repeats", "warmup", "loop_cap", "data_dir") if (v := getattr(args, k)) is not None}
    kw.update(dtypes=("float32", "float64") if args.dtype == "both" else (args.dtype,), verbose=not args.quiet,
              accelerator=accelerator)
    if args.batches:
        kw["batches"] = tuple(int(b) for b in args.batches.split(","))
    if args.only:
        kw["only"] = tuple(x.strip() for x in args.only.split(",") if x.strip())
    config = (BenchConfig.make_quick(**kw) if args.quick else BenchConfig.make_accelerator(**kw) if accelerator
              else BenchConfig(**kw))

    env = collect_environment()
    command = " ".join(["python -m benchmarks", *argv])
    mode = "quick (smoke test; not for quoting)" if config.quick else "full"
    if accelerator:
        mode = ("quick, on the accelerator (smoke test; not for quoting)" if config.quick else
                f"accelerator sizes (--gpu): {ACCELERATOR_SIZES_TEXT}")
    elif args.gpu:
        mode = f"--gpu without an accelerator (jax backend {backend}): the small sizes of a {mode} run"
    settings = {
        "mode": mode,
        "dtypes": ", ".join(config.dtypes),
        "repeats / warm-up": f"{config.repeats} / {config.warmup} (median and min; sampling stops after "
        f"{config.max_row_s:g} s per row, with at least 3 samples)",
        "Python-loop cap": f"{config.loop_cap} configurations per timed call",
        "data": str(config.data_dir),
    }
    if budgets or total_s is not None:
        settings["time budgets"] = (
            (_budget_text(budgets, names) if budgets else "none per section")
            + ("" if total_s is None else f"; {total_s:g} s for the whole run, of which a section gets at most what "
               "is left") + ". Cooperative: a row expected to end past its section's budget is not started and says "
            "so, near it a row takes 1 sample, and a row that started in time runs to its end")
    if config.only:
        settings["implementations"] = "only those matching " + ", ".join(config.only)
    config.log(f"running {names} ({settings['mode']}), report -> {args.out}")
    write = _writer(args.out, env, command, settings)
    write([])  # the header at once: the file names the device and versions before the first row
    run_benchmarks(names, config, command, budgets=budgets, write=write, total_s=total_s, rerun_busy=not args.quick)
    config.log(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
