"""`make bench`: every benchmark, one after the other, each printing its own table.

Ratios against peers measured in the same run are the evidence; absolute times on a shared
machine are not. Pass names to run a subset: `python -m benchmarks.run_all localize fusion`.
"""

from __future__ import annotations

import importlib
import sys
import time

BENCHMARKS = {
    "localize": "benchmarks.bench_localize",  # one scan vs OpenCV's Hough voting; scaling
    "fusion": "benchmarks.bench_fusion",  # replay speed, memory, accuracy of the filter
    "global": "benchmarks.bench_global",  # global set matching vs map size
    "rerun": "benchmarks.bench_rerun",  # replay with the Rerun recording on and off
    "ros2": "benchmarks.bench_ros2",  # the ROS 2 node's throughput and latency (ros2 extra)
}


def main(argv: list[str]) -> int:
    names = argv or list(BENCHMARKS)
    unknown = [n for n in names if n not in BENCHMARKS]
    if unknown:
        print(f"unknown benchmark(s): {', '.join(unknown)}; known: {', '.join(BENCHMARKS)}")
        return 2
    for name in names:
        try:
            module = importlib.import_module(BENCHMARKS[name])
        except ModuleNotFoundError as exc:
            print(f"\n== {name}: not available ({exc.name})")
            continue
        print(f"\n== {name} " + "=" * (70 - len(name)))
        started = time.perf_counter()
        module.main([])
        print(f"({name}: {time.perf_counter() - started:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
