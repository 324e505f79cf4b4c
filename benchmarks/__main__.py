"""Command line: ``python -m benchmarks [NAME ...] [--quick] [--dtype ...] [--out BENCHMARKS.md]`` runs the
benchmarks in this process (progress on stderr) and writes the report; x64 is on before anything touches JAX."""

from __future__ import annotations

import argparse
import pathlib
import sys
from collections.abc import Sequence

from . import REGISTRY, BenchConfig, default_data_dir, run_benchmarks
from .report import collect_environment, render_report


def _parser() -> argparse.ArgumentParser:
    names = "\n".join(f"  {s.name:10s} {s.description}" for s in REGISTRY.values())
    p = argparse.ArgumentParser(
        prog="python -m benchmarks",
        description="Benchmark jaxanim against its peers and write BENCHMARKS.md.",
        epilog=f"registered benchmarks:\n{names}",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    arg = p.add_argument
    arg("names", nargs="*", metavar="NAME", help="benchmarks to run (default: all registered)")
    arg("--quick", action="store_true", help="batches 1 and 8, 3 repeats, loops capped at 8: a smoke test")
    arg("--dtype", choices=("float32", "float64", "both"), default="both", help="default: both")
    arg("--out", type=pathlib.Path, default=pathlib.Path("BENCHMARKS.md"), help="default: BENCHMARKS.md")
    arg("--batches", type=str, default=None, help="comma-separated batch sizes, overriding every benchmark's")
    arg("--repeats", type=int, default=None, help="timed samples per row (default 7, quick 3)")
    arg("--warmup", type=int, default=None, help="untimed calls per row (default 2, quick 1)")
    arg("--loop-cap", type=int, default=None, help="max configurations per timed Python-loop call (default 2048)")
    arg("--only", type=str, default=None, help="comma-separated shell patterns: run only the implementations whose "
        "name matches one, case-insensitive (e.g. 'jaxanim*,pinocchio*')")
    arg("--data-dir", type=pathlib.Path, default=None, help=f"shared data folder (default {default_data_dir()})")
    arg("--quiet", action="store_true", help="no progress on stderr")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Parse ``argv``, run the benchmarks, write the report; return the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args = _parser().parse_args(argv)
    unknown = [n for n in args.names if n not in REGISTRY]
    if unknown:
        _parser().error(f"unknown benchmark(s) {unknown}; registered: {', '.join(REGISTRY)}")

    import jax

    jax.config.update("jax_enable_x64", True)  # float64 rows and references; float32 rows are explicit

    kw = {k: v for k in ("repeats", "warmup", "loop_cap", "data_dir") if (v := getattr(args, k)) is not None}
    kw.update(dtypes=("float32", "float64") if args.dtype == "both" else (args.dtype,), verbose=not args.quiet)
    if args.batches:
        kw["batches"] = tuple(int(b) for b in args.batches.split(","))
    if args.only:
        kw["only"] = tuple(x.strip() for x in args.only.split(",") if x.strip())
    config = BenchConfig.make_quick(**kw) if args.quick else BenchConfig(**kw)

    env = collect_environment()
    command = " ".join(["python -m benchmarks", *argv])
    settings = {
        "mode": "quick (smoke test; not for quoting)" if config.quick else "full",
        "dtypes": ", ".join(config.dtypes),
        "repeats / warm-up": f"{config.repeats} / {config.warmup} (median and min; sampling stops after "
        f"{config.max_row_s:g} s per row, with at least 3 samples)",
        "Python-loop cap": f"{config.loop_cap} configurations per timed call",
        "data": str(config.data_dir),
    }
    if config.only:
        settings["implementations"] = "only those matching " + ", ".join(config.only)
    config.log(f"running {args.names or list(REGISTRY)} ({settings['mode']}), report -> {args.out}")
    tables = run_benchmarks(args.names, config, command)
    args.out.write_text(render_report(env, command, settings, tables), encoding="utf-8")
    config.log(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
