"""Benchmarks of the running graph (``python -m gldt_ros.bench.<name>``); not unit tests."""
