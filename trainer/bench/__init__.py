"""Benchmarks behind ``handover bench``: pareto (error against run time), latency, throughput."""
