"""Throughput and memory benchmarks (`make bench`); numbers are printed, never asserted."""
