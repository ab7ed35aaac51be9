"""Benchmarks behind ``gldt bench``; each module registers one topic (see ``gldt_core.cli.bench``)."""
