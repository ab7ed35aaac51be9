"""``gldt bench <topic>``: benchmarks that print ratios against a peer measured in the same run.

Each module in :mod:`gldt_core.bench` that defines ``register(subparsers)`` adds one topic
(tracking, detection, ablation, synth, ...), so benchmarks are added without editing this file.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``gldt bench`` and one sub-subcommand per benchmark module."""
    import gldt_core.bench as bench_package

    parser = subparsers.add_parser("bench", help="run a benchmark (tracking, detection, ...)")
    topics = parser.add_subparsers(dest="topic", metavar="TOPIC", required=True)
    for module_info in sorted(pkgutil.iter_modules(bench_package.__path__), key=lambda m: m.name):
        if module_info.name.startswith("_"):
            continue
        module = importlib.import_module(f"gldt_core.bench.{module_info.name}")
        topic_register = getattr(module, "register", None)
        if topic_register is not None:
            topic_register(topics)
