"""Run every benchmark that this checkout has."""
import importlib

for name in ("bench_replay", "bench_monitor", "bench_opcua", "bench_plant", "bench_diagnose", "bench_bmv2"):
    try:
        module = importlib.import_module(f"bench.{name}")
    except ModuleNotFoundError as exc:
        if exc.name == f"bench.{name}":
            continue
        raise
    print(f"== {name}")
    module.main()
    print()
